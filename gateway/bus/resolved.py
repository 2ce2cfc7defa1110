"""Each configured node resolved once: its profile on its EDS, its settings, its boot steps and
the PDO codecs they leave in the device, its refresh plan and its mapping reads.

``resolve_config(cfg)`` builds one ``ResolvedNode`` per node whose profile loads (a node whose
profile or EDS does not load is reported by the config loader and left out). ``check``, the
master, the register map, the Zenoh key listing, the simulator, the web console and the
command-line tools all read these: none of them loads a profile, builds boot steps or compiles
codecs again.

A node whose boot configuration cannot be built (an object missing from the EDS, a value that
does not fit) is resolved with ``boot_error`` set and no steps or codecs: ``check`` reports it,
and the master refuses it (``ResolvedNode.require``).

Imports: cia301, config (types), profiles, profiles.layout, objref, bus.node.settings,
bus.node.boot_steps, pdo.codec, pdo.refresh, pdo.verify. Nothing northbound, no I/O but reading
the device files.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from gateway.bus.node.boot_steps import ConfigStep, build_boot_steps
from gateway.bus.node.settings import NodeSettings, resolve_node_settings
from gateway.cia301 import TRANSMISSION_SYNC
from gateway.config import Config, ConfigError, NodeConfig
from gateway.objref import ObjRef
from gateway.pdo.codec import RpdoCodec, TpdoCodec, compile_node
from gateway.pdo.refresh import Refresh, refresh_plan
from gateway.pdo.verify import MappingRead, mapping_reads
from gateway.profiles import LoadedProfile, ProfileError, load_node_profile, node_verifies_mapping
from gateway.profiles.layout import pdo_objects


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


def resolve_node(cfg: Config, ncfg: NodeConfig) -> ResolvedNode:
    """One node (ProfileError when its profile or EDS does not load)."""
    lp = load_node_profile(ncfg, cfg.base_dir)
    settings = resolve_node_settings(cfg.master, ncfg, lp.profile)
    try:
        steps = build_boot_steps(
            lp,
            ncfg,
            ncfg.supervision,
            ncfg.heartbeat_ms,
            ncfg.guard_time_ms,
            ncfg.life_time_factor,
        )
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
        if ncfg.configure and node_verifies_mapping(lp, ncfg, ncfg.eds_only)
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


def resolve_config(cfg: Config, names: Iterable[str] | None = None) -> dict[str, ResolvedNode]:
    """Node name -> its resolution, in config order (``names``: only these nodes)."""
    wanted = set(names) if names is not None else None
    out: dict[str, ResolvedNode] = {}
    for ncfg in cfg.nodes:
        if wanted is not None and ncfg.name not in wanted:
            continue
        try:
            out[ncfg.name] = resolve_node(cfg, ncfg)
        except ProfileError:
            continue  # reported by the config loader
    return out


def nodes_of(cfg: Config, nodes: dict[str, ResolvedNode] | None) -> dict[str, ResolvedNode]:
    """``nodes`` when the caller resolved them, else the config resolved now (a consumer built
    on its own, as in a unit test)."""
    return nodes if nodes is not None else resolve_config(cfg)


def node_of(cfg: Config, nodes: dict[str, ResolvedNode], ncfg: NodeConfig) -> ResolvedNode:
    """The resolution of ``ncfg``; a node left out of ``nodes`` is resolved again, which raises
    the loader's ProfileError (as reading its profile always did)."""
    return nodes.get(ncfg.name) or resolve_node(cfg, ncfg)
