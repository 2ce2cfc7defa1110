"""Each configured node resolved once: its profile on its EDS, its settings, its boot steps and
the PDO codecs they leave in the device, its refresh plan and its mapping reads.

``resolve_nodes(cfg)`` is the one resolution: it loads each node's profile on its EDS (the
only caller of ``load_node_profile``), finds the node's problems (a profile or EDS that does not
load, a signal override, PDO variant or ``verify_mapping`` the profile does not allow) and
builds one ``ResolvedNode`` per node whose profile loads. ``load_resolved`` / ``parse_resolved``
read and validate a config file (``canopen_gateway.config``) and resolve its nodes in one pass, every
problem in one ConfigError. ``check``, the master, the register map, the Zenoh key listing, the
frame decoder, the simulator, the web console and the command-line tools all take these as a
required argument: none of them loads a profile, builds boot steps or compiles codecs again.

A node whose boot configuration cannot be built (an object missing from the EDS, a value that
does not fit) is resolved with ``boot_error`` set and no steps or codecs: ``check`` reports it,
and the master refuses it (``ResolvedNode.require``).

Imports: canopen.cia301, config (types and loaders), profiles, profiles.layout, canopen.objref, device.settings,
device.boot_steps, pdo.codec, pdo.refresh, pdo.verify. Nothing northbound, no I/O but reading
the device files.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from canopen_gateway.canopen.cia301 import TRANSMISSION_SYNC
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import Config, ConfigError, NodeConfig, load_config, parse_config
from canopen_gateway.device.boot_steps import ConfigStep, build_boot_steps
from canopen_gateway.device.settings import NodeSettings, resolve_node_settings
from canopen_gateway.pdo.codec import RpdoCodec, TpdoCodec, compile_node
from canopen_gateway.pdo.refresh import Refresh, refresh_plan
from canopen_gateway.pdo.verify import MappingRead, mapping_reads
from canopen_gateway.profiles import (
    LoadedProfile,
    ProfileError,
    load_node_profile,
    node_verifies_mapping,
)
from canopen_gateway.profiles.layout import pdo_objects


class NamedNode:
    """``name`` and ``node_id`` of what is built for one node, read from its config ``cfg``
    (``ResolvedNode`` here, the master's ``NodeParts``)."""

    cfg: NodeConfig

    @property
    def name(self) -> str:
        return self.cfg.name

    @property
    def node_id(self) -> int:
        return self.cfg.node_id


@dataclass(frozen=True, eq=False)
class ResolvedNode(NamedNode):
    """One node as the whole gateway sees it (see the module docstring)."""

    cfg: NodeConfig
    lp: LoadedProfile
    settings: NodeSettings
    #: the ordered SDO writes of the boot configuration (empty when ``boot_error``)
    boot_steps: list[ConfigStep] = field(default_factory=list)
    #: the boot steps' writes the codecs follow (none for a node the gateway does not configure)
    pdo_writes: list[tuple[ObjRef, Any]] = field(default_factory=list)
    tpdos: list[TpdoCodec] = field(default_factory=list)
    rpdos: list[RpdoCodec] = field(default_factory=list)
    #: values read by SDO right after NMT start (``refresh_on_start``)
    refresh: list[Refresh] = field(default_factory=list)
    #: the mapping objects read back before NMT start (``verify_mapping``)
    verify: tuple[MappingRead, ...] = ()
    #: why the boot configuration or the codecs cannot be built (``check`` reports it)
    boot_error: ValueError | KeyError | None = None
    #: the enabled TPDOs that are SYNC-driven (transmission type 0..240) as the boot
    #: configuration leaves them: sent only when a SYNC producer runs
    sync_tpdos: tuple[int, ...] = ()

    @property
    def stale_after_s(self) -> float | None:
        """The node's ``stale_after_ms`` (else the one derived for an unsupervised EDS-only
        node), in seconds; None: values do not age."""
        stale_ms = self.cfg.stale_after_ms or self.lp.stale_after_ms
        return stale_ms / 1000.0 if stale_ms else None

    def require(self) -> ResolvedNode:
        """This node, or ConfigError when its boot configuration cannot be built."""
        if self.boot_error is not None:
            raise ConfigError([f"node {self.name}: {self.boot_error}"])
        return self


def resolve_node(cfg: Config, ncfg: NodeConfig, lp: LoadedProfile) -> ResolvedNode:
    """One node on its loaded profile ``lp``."""
    settings = resolve_node_settings(cfg.master, ncfg, lp.profile)
    setup = ncfg.setup
    try:
        steps = build_boot_steps(lp, setup)
        # The decoder follows the mapping the boot configuration leaves in the device.
        writes = [(st.object, st.value) for st in steps] if ncfg.configure else []
        tpdos, rpdos = compile_node(lp, ncfg.node_id, ncfg.pdo_variant, writes)
    except (ValueError, KeyError) as exc:
        return ResolvedNode(ncfg, lp, settings, boot_error=exc)
    plan = (
        refresh_plan(lp, ncfg.node_id, ncfg.pdo_variant, tpdos, writes)
        if settings.refresh_on_start
        else []
    )
    verify = (
        tuple(mapping_reads(lp, ncfg.node_id, ncfg.pdo_variant))
        if ncfg.configure and node_verifies_mapping(lp, setup)
        else ()
    )
    sync = sync_driven_tpdos(lp, ncfg.pdo_variant, tpdos, writes)
    return ResolvedNode(ncfg, lp, settings, steps, writes, tpdos, rpdos, plan, verify, sync_tpdos=sync)


def sync_driven_tpdos(
    lp: LoadedProfile, variant: int | None, tpdos: list[TpdoCodec], writes: list[tuple[ObjRef, Any]]
) -> tuple[int, ...]:
    """The numbers of ``tpdos`` whose transmission type (the layout's, then the last boot
    write of 180xh:02) is synchronous (CiA 301 7.5.2.35: 0..240)."""
    layout, _ = lp.profile.layout(variant if lp.profile.pdo_variants else None)
    types = {p.number: p.transmission_type for p in layout}
    out = []
    for c in tpdos:
        comm, _ = pdo_objects(lp.profile, "tpdo", c.number)
        for obj, value in writes:
            if obj == ObjRef(comm, 0x02) and isinstance(value, int):
                types[c.number] = value
        if types.get(c.number) in TRANSMISSION_SYNC:
            out.append(c.number)
    return tuple(out)


#: one problem of a node: (key path, what is allowed)
Problem = tuple[str, str]


def _profile_problems(key: str, n: NodeConfig, lp: LoadedProfile) -> list[Problem]:
    """What node ``n`` (at key path ``key``) asks of its loaded profile that the profile has
    not: a signal override, a PDO variant, ``verify_mapping``."""
    out: list[Problem] = []
    names = {s.name for s in lp.profile.signals}
    for s in n.signals:
        if s not in names:
            out.append(
                (
                    f"{key}.signals.{s}",
                    (f"profile {n.profile}" if n.profile else n.device)
                    + f" has no signal {s!r}; it has: "
                    + ", ".join(sorted(names)),
                )
            )
    if n.pdo_variant is not None:
        var = lp.profile.pdo_variants
        if var is None:
            out.append((f"{key}.pdo_variant", f"profile {n.profile} has no PDO variants"))
        elif n.pdo_variant not in var.variants:
            out.append(
                (
                    f"{key}.pdo_variant",
                    f"got {n.pdo_variant!r}, profile {n.profile} allows {sorted(var.variants)}",
                )
            )
    if n.verify_mapping and lp.profile.verify_mapping is False:
        out.append(
            (
                f"{key}.verify_mapping",
                f"profile {n.profile}: its mapping objects do not describe the layout in use; "
                "must be false",
            )
        )
    return out


def resolve_nodes(cfg: Config) -> tuple[dict[str, ResolvedNode], list[Problem]]:
    """Node name -> its resolution, in config order, and the nodes' problems. A node with a
    problem (its profile or EDS does not load, it asks what its profile has not) is left out,
    its problem said."""
    out: dict[str, ResolvedNode] = {}
    problems: list[Problem] = []
    for view in cfg.network_views():  # each node with its network's master settings
        for i, ncfg in enumerate(view.nodes):
            key = view.qualify(f"nodes[{i}]")
            try:
                lp = load_node_profile(ncfg.setup, cfg.base_dir)
            except ProfileError as exc:
                if exc.key is not None:
                    problems.append((f"{key}.{exc.key}" if exc.key else key, str(exc)))
                else:
                    where = f"{key}.{'eds' if ncfg.eds else 'profile'}"
                    problems += [(where, line) for line in str(exc).splitlines()]
                continue
            asked = _profile_problems(key, ncfg, lp)
            problems += asked
            if not asked:
                out[ncfg.name] = resolve_node(view, ncfg, lp)
    return out, problems


class Resolved(NamedTuple):
    """A config and its nodes, resolved once (``cfg, nodes = load_resolved(path)``)."""

    cfg: Config
    nodes: dict[str, ResolvedNode]


def parse_resolved(
    raw: Any, source: str = "<memory>", environ: Mapping[str, str] | None = None
) -> Resolved:
    """``canopen_gateway.config.parse_config`` and the nodes resolved in the same pass: the problems of
    both in one ConfigError."""
    found: dict[str, ResolvedNode] = {}
    cfg = parse_config(raw, source, environ, resolve=_resolver(found))
    return Resolved(cfg, found)


def load_resolved(path: str | os.PathLike[str], environ: Mapping[str, str] | None = None) -> Resolved:
    """``canopen_gateway.config.load_config`` and the nodes resolved in the same pass."""
    found: dict[str, ResolvedNode] = {}
    cfg = load_config(path, environ, resolve=_resolver(found))
    return Resolved(cfg, found)


def _resolver(found: dict[str, ResolvedNode]) -> Callable[[Config], list[Problem]]:
    """The hook the config loader calls on a config whose sections validate: resolves its nodes
    into ``found`` and returns their problems."""

    def resolve(cfg: Config) -> list[Problem]:
        nodes, problems = resolve_nodes(cfg)
        found.update(nodes)
        return problems

    return resolve
