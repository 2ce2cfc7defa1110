"""Checks across the config, the profiles / EDS files and the register map
(``canopen-gateway check``, and every start of the gateway).

``config_problems(cfg)`` returns one ``(key path, what is allowed)`` per problem (the checks of
one bus run on each network's config, ``Config.network_view``, their keys under its
``networks[k].``):

* the register map compiles (no address used twice, blocks fit);
* protocol feasibility, e.g. an AP05 external heartbeat (AP05 manual 5.5.4, 5F09h) that the
  SYNC period or the RPDO keep-alive cannot feed in time, node guarding without times;
* the boot configuration of every node can be built (objects in the EDS, writable, values that
  fit their type) and each value it writes lies within the EDS LowLimit/HighLimit and the
  profile's ``constraints`` (e.g. 1017h "0 or 10..65535");
* every PDO of the node's layout against its EDS (CiA 301 7.5.2.36/38): each mapped object and
  sub-index exists, the entry's bit length is the object's, TPDO entries are readable and
  PDO-mappable, RPDO entries writable and PDO-mappable, at most 64 bits; a PDO that is not
  written at boot has the EDS mapping; a PDO written at boot differs from the EDS only where
  the EDS mapping objects are writable;
* a signal's declared type is the EDS DataType; a signal declared as a PDO signal is in a PDO;
* every safe output value (``safe_value``, ``nodes[].safe_outputs``) names an RPDO output of its
  node and fits its type and range (``canopen_gateway.modbus.safe_outputs``);
* no COB-ID has two uses (``canopen_gateway.bus.cob_id_uses``: the PDOs, EMCY, SDO and heartbeat of every
  node, the master's NMT, SYNC, heartbeat and LSS), named in one line with where each got it;
  one SYNC producer (``master.sync_period_ms`` and ``master.sync_external`` not both);
* ``journal.path`` can be created and written (the one check here that touches the disk: it
  creates the directory when missing);
* the secrets named by file are usable (``checks.secrets``: ``web.token_file``, a
  ``zenoh.auth.password_file`` that is not the examples' placeholder, the certificate and key
  of ``health.tls``).

``config_warnings(cfg)`` (what runs but may not do what is meant) and ``config_notes(cfg)``
(what the gateway will not check) are ``checks.warnings``'s, re-exported here.

``pair_problems(a, b, nodes_a, nodes_b)`` (``checks.pair``) compares the two configs of a
hot-standby pair (``check -c A -c B``, docs/redundancy.md); ``pair_of_networks`` does it
network by network.

Every function takes the nodes as resolved once (``canopen_gateway.device.resolved``). ``load_checked`` /
``parse_checked`` read and validate a config, resolve its nodes in the same pass and run these
checks, raising ConfigError with every line; they return the config and its nodes.

Pure: imports config, device.resolved (the resolution and its loaders), checks.pair, checks.warnings, checks.secrets, profiles,
eds, the boot step builder, the external heartbeat keep-alive rule (device/settings.py), the codecs and the
register map, the COB-IDs of the nodes (bus/cob_id_uses.py), journal (the path check) (no I/O but reading the files they name and the
journal's directory).

Imports: config, checks.pair, checks.warnings, checks.secrets, canopen.cia301, canopen.objref, bus.cob_id_uses, device (boot_steps, resolved,
settings), eds (parse, pdos), profiles (layout, schema), modbus.safe_outputs (its
rule only), northbound.regmap, journal.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from canopen_gateway.bus.cob_id_uses import clashes, gateway_uses, loops_back
from canopen_gateway.canopen.cia301 import TYPE_BITS, TYPE_NAMES
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.checks.pair import pair_problems
from canopen_gateway.checks.secrets import secret_problems
from canopen_gateway.checks.warnings import config_notes, config_warnings
from canopen_gateway.config import Config, ConfigError, NodeConfig, blame
from canopen_gateway.device.boot_steps import ConfigStep
from canopen_gateway.device.resolved import Resolved, ResolvedNode, load_resolved, parse_resolved
from canopen_gateway.device.settings import external_heartbeat_problem
from canopen_gateway.eds.parse import DATA_TYPES
from canopen_gateway.eds.pdos import eds_pdos, od_var, readable
from canopen_gateway.journal import path_problem
from canopen_gateway.modbus.safe_outputs import safe_output_problems
from canopen_gateway.northbound.regmap import RegisterMapError, build_register_map
from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.profiles.layout import pdo_objects
from canopen_gateway.profiles.schema import TYPE_BITS as SIGNAL_BITS
from canopen_gateway.profiles.schema import Pdo

Problem = tuple[str, str]


def boot_problems(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """Boot steps that cannot be built, values outside the EDS limits or the profile's
    constraints, and PDO mappings they leave that cannot be decoded."""
    out: list[Problem] = []
    resolved = nodes
    for i, n in enumerate(cfg.nodes):
        if not n.configure:
            continue
        rn = resolved.get(n.name)
        if rn is None:
            continue  # its profile does not load: reported by the config loader
        lp, steps = rn.lp, rn.boot_steps
        exc = rn.boot_error
        if exc is not None:
            head, _, rest = str(exc).partition(": ")
            if head.split(".")[0] in ("tpdo", "rpdo") and rest:
                out.append((f"nodes[{i}].{head}", rest))
            else:
                out.append((f"nodes[{i}]", str(exc)))
            continue
        out += _limit_problems(lp, n, i, steps, cfg)
    return out


def _limit_problems(
    lp: LoadedProfile, n: NodeConfig, i: int, steps: list[ConfigStep], cfg: Config
) -> list[Problem]:
    out: list[Problem] = []
    constraints = lp.profile.constraints
    for s in steps:
        if not isinstance(s.value, int) or isinstance(s.value, bool):
            continue
        var = lp.od_var(s.object)
        key = f"nodes[{i}].{s.source}" if s.source else f"profile {lp.profile.family} boot ({s.object})"
        lo = getattr(var, "min", None)
        hi = getattr(var, "max", None)
        if lo is not None and hi is not None and lo > hi:
            lo = hi = None  # an EDS with LowLimit > HighLimit (e.g. 0/0 placeholders) says nothing
        if lo is not None and hi is not None and lo == hi == 0:
            lo = hi = None
        if (lo is not None and s.value < lo) or (hi is not None and s.value > hi):
            out.append(
                (
                    key,
                    f"{s.value} for {s.object} ({s.description}) is outside "
                    f"{lo if lo is not None else ''}..{hi if hi is not None else ''} "
                    f"(LowLimit/HighLimit in {lp.eds_path.name})",
                )
            )
        c = constraints.get(s.object)
        if c is not None and not c.admits(s.value):
            note = f"; {c.note}" if c.note else ""
            out.append(
                (
                    key,
                    f"{s.value} for {s.object} ({s.description}) is not allowed: "
                    f"{c.allowed} (profile {lp.profile.family}){note}",
                )
            )
    return out


def _written_pdos(lp: LoadedProfile, steps: list[ConfigStep], kind: str) -> set[int]:
    """Numbers of the PDOs whose mapping the boot steps write."""
    out = set()
    for number in range(1, 513):
        _, mapping = pdo_objects(lp.profile, kind, number)  # type: ignore[arg-type]
        if any(s.object.index == mapping for s in steps):
            out.add(number)
    return out


def eds_problems(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """Every PDO of each node's layout and every signal against the node's EDS."""
    out: list[Problem] = []
    resolved = nodes
    for i, n in enumerate(cfg.nodes):
        rn = resolved.get(n.name)
        if rn is None:
            continue
        lp = rn.lp
        key = f"nodes[{i}]"
        eds = lp.eds_path.name
        od = lp.od
        steps: list[ConfigStep] | None = (
            [] if not n.configure else None if rn.boot_error is not None else rn.boot_steps
        )  # None: reported by boot_problems
        tpdos, rpdos = lp.profile.layout(n.pdo_variant if lp.profile.pdo_variants else None)
        trusted = lp.profile.verify_mapping is not False  # mapping objects describe the layout
        for kind, pdos in (("tpdo", tpdos), ("rpdo", rpdos)):
            settings = n.tpdo if kind == "tpdo" else n.rpdo
            written = _written_pdos(lp, steps or [], kind) | set(settings)
            held = {p.number: p for p in eds_pdos(od, n.node_id, kind)}  # type: ignore[arg-type]
            for p in pdos:
                where = f"{key}.{kind}.{p.number}" if p.number in (n.tpdo if kind == "tpdo" else n.rpdo) else f"{key} ({kind.upper()}{p.number})"  # fmt: skip
                if p.origin != "eds":  # the file's own PDOs: checked when loaded (warnings)
                    out += _pdo_entry_problems(lp, kind, p, where, eds)
                e = held.get(p.number)
                if e is None or not trusted:
                    continue
                entries = [(x.object, x.bits) for x in p.mapping]
                same = list(e.entries) == entries
                if p.number in written:
                    if not same and not e.mapping_writable and steps is not None:
                        out.append(
                            (
                                f"{where}.mapping" if "." in where.split("]")[-1] else where,
                                f"{kind.upper()}{p.number} mapping {_fmt(entries)} differs from the "
                                f"EDS {_fmt(list(e.entries))}, and {e.map_index:04X}h is read-only "
                                f"in {eds}: the device cannot be remapped",
                            )
                        )
                elif not same and p.origin != "eds":
                    out.append(
                        (
                            where,
                            f"{kind.upper()}{p.number} layout {_fmt(entries)} is not the EDS "
                            f"mapping {_fmt(list(e.entries))} and is not written at boot: "
                            "it would be decoded with the wrong layout",
                        )
                    )
        # signals
        all_pdo_objs = {x.object for p in (*tpdos, *rpdos) for x in p.mapping}
        prof = lp.profile
        if prof.pdo_variants:
            for v in prof.pdo_variants.variants.values():
                all_pdo_objs |= {x.object for p in (*v.tpdos, *v.rpdos) for x in p.mapping}
        for s in prof.signals:
            var = od_var(od, s.object)
            if var is None:
                continue
            eds_type = TYPE_NAMES.get(var.data_type)
            eds_bits = TYPE_BITS.get(var.data_type)
            if s.type not in ("string", "bytes") and eds_type is not None and s.type != eds_type:
                # a signed reading of an unsigned object of the same size is a profile's choice
                # (AP05 positions are UNSIGNED32 in the manual, negative in practice)
                if SIGNAL_BITS.get(s.type or "") != eds_bits:
                    out.append(
                        (
                            f"{key} ({prof.family} signal {s.name})",
                            f"type {s.type} but {s.object} is {DATA_TYPES.get(var.data_type or 0, '?')} "
                            f"in {eds}: must be {eds_type} (or another {eds_bits}-bit type)",
                        )
                    )
            if s.transport == "pdo" and s.object not in all_pdo_objs:
                out.append(
                    (
                        f"{key} ({prof.family} signal {s.name})",
                        f"declared as a PDO signal, but {s.object} is in no PDO of the layout",
                    )
                )
    return out


def _fmt(entries: list[tuple[ObjRef, int]]) -> str:
    return "[" + ", ".join(f"{o}/{b}" for o, b in entries) + "]"


def _pdo_entry_problems(lp: LoadedProfile, kind: str, p: Pdo, where: str, eds: str) -> list[Problem]:
    out: list[Problem] = []
    total = 0
    for j, e in enumerate(p.mapping):
        total += e.bits
        w = f"{where}.mapping[{j}]" if "." in where.split("]")[-1] else where
        if e.object.index < 0x1000:
            bits = TYPE_BITS.get(e.object.index)
            if bits is None or bits != e.bits:
                out.append((w, f"dummy entry {e.object}/{e.bits}: data type {e.object.index:04X}h is "
                               f"{bits if bits else 'not a dummy type'} bit"))  # fmt: skip
            continue
        var = od_var(lp.od, e.object)
        if var is None:
            entry = lp.od.get(e.object.index)
            what = (
                f"{e.object.index:04X}h has no sub-index {e.object.sub:02X}h"
                if entry is not None
                else f"{e.object} is not in {eds}"
            )
            out.append((w, f"{kind.upper()}{p.number} entry {e.object}: {what}"))
            continue
        bits = TYPE_BITS.get(var.data_type)
        if bits is not None and bits != e.bits:
            out.append(
                (
                    w,
                    f"{kind.upper()}{p.number} entry {e.object}/{e.bits}: the object is "
                    f"{DATA_TYPES.get(var.data_type or 0, '?')} ({bits} bit) in {eds}; must be /{bits}",
                )
            )
        if not var.pdo_mappable:
            out.append((w, f"{kind.upper()}{p.number} entry {e.object}: not PDO-mappable (PDOMapping=0) in {eds}"))  # fmt: skip
        if kind == "tpdo" and not readable(var):
            out.append((w, f"TPDO{p.number} entry {e.object}: not readable ({var.access_type}) in {eds}"))  # fmt: skip
        if (
            kind == "rpdo"
            and var.access_type not in ("rw", "wo", "rww", "rwr")
            and e.object not in lp.profile.rpdo_only_writable
        ):
            out.append((w, f"RPDO{p.number} entry {e.object}: not writable ({var.access_type}) in {eds}"))  # fmt: skip
    if total > 64:
        out.append((where, f"{kind.upper()}{p.number} maps {total} bits; a PDO carries at most 64"))
    return out


def protocol_problems(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    resolved = nodes
    out: list[Problem] = boot_problems(cfg, resolved)
    for i, n in enumerate(cfg.nodes):
        key = f"nodes[{i}]"
        rn = resolved.get(n.name)
        if rn is None:
            continue
        lp = rn.lp
        if n.external_heartbeat is not None:
            if "external_heartbeat" not in lp.profile.features:
                out.append(
                    (f"{key}.external_heartbeat", f"{n.device} has no external heartbeat")
                )
                continue
            eh = n.external_heartbeat
            problem = external_heartbeat_problem(
                key, n.name, eh.interval_ms, eh.source, eh.keepalive_ms, cfg.master.sync_period_ms
            )
            if problem is not None:
                out.append(problem)
        sup = n.supervision or lp.profile.boot.supervision
        if sup == "guarding":
            gt = n.guard_time_ms if n.guard_time_ms is not None else lp.profile.boot.guard_time_ms
            ltf = (
                n.life_time_factor
                if n.life_time_factor is not None
                else lp.profile.boot.life_time_factor
            )
            if not gt or not ltf:
                out.append(
                    (f"{key}.guard_time_ms", "node guarding needs guard_time_ms and life_time_factor > 0")
                )
    return out


def cob_id_problems(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """Every COB-ID with two uses (a node's and another node's, or the master's), at the
    later one's key; and two SYNC producers."""
    out: list[Problem] = []
    if cfg.master.sync_external and cfg.master.sync_period_ms:
        out.append(
            (
                "master.sync_external",
                "true says another master produces SYNC, but master.sync_period_ms "
                f"{cfg.master.sync_period_ms:g} makes this gateway produce it too; one SYNC "
                "producer per bus (CiA 301 7.2.5): set one of them",
            )
        )
    for first, later in clashes(gateway_uses(cfg, nodes)):
        if loops_back(first, later):
            continue  # a warning (config_warnings)
        out.append(
            (
                later.key,
                f"COB-ID 0x{later.cob_id:03X} of {later} is also {first}: one COB-ID cannot "
                "serve both (the frames of one would be taken for the other's)",
            )
        )
    return out


def journal_path(cfg: Config) -> Path | None:
    """The journal's directory (``journal.path`` relative to the config file), or None."""
    if cfg.journal.path is None:
        return None
    return cfg.base_dir / Path(cfg.journal.path).expanduser()


def journal_problems(cfg: Config) -> list[Problem]:
    """``journal.path`` must be a directory this process can create and write."""
    path = journal_path(cfg)
    why = None if path is None else path_problem(path)
    return [] if why is None else [("journal.path", why)]


def config_problems(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """Every cross-check (see the module docstring), in a stable order."""
    out: list[Problem] = []
    resolved = nodes
    try:
        build_register_map(cfg, resolved)  # one map for every network's nodes
    except RegisterMapError as exc:
        out.append((cfg.qualify(exc.key), str(exc)))
    for view in cfg.network_views():  # what one bus holds: each network's alone
        found = protocol_problems(view, resolved) + eds_problems(view, resolved)
        found += safe_output_problems(view, resolved) + cob_id_problems(view, resolved)
        out += [(view.qualify(k), m) for k, m in found]
    out += journal_problems(cfg)
    out += secret_problems(cfg)
    seen: set[Problem] = set()
    unique = []
    for p in out:
        if p not in seen:
            seen.add(p)
            unique.append(p)
    return unique


def check_config(cfg: Config, nodes: dict[str, ResolvedNode]) -> Config:
    """Raise ConfigError (one line per problem: file, key path, what is allowed)."""
    problems = config_problems(cfg, nodes)
    if problems:
        raise ConfigError([f"{blame(k, cfg.source, cfg.env_keys)}: {k}: {m}" for k, m in problems])
    return cfg


def pair_of_networks(
    a: Config, b: Config, nodes_a: dict[str, ResolvedNode], nodes_b: dict[str, ResolvedNode]
) -> list[str]:
    """The two configs of a pair compared network by network (``pair_problems`` of each
    network's config, its keys under ``networks[k].``): they must have the same networks."""
    both = f"{a.source}, {b.source}"
    if a.network_names() != b.network_names():
        return [f"{both}: networks: {', '.join(a.network_names())} in {a.source}, "
                f"{', '.join(b.network_names())} in {b.source}: a pair has the same networks"]  # fmt: skip
    out: list[str] = []
    for name in a.network_names():
        va, vb = a.network_view(name), b.network_view(name)
        for line in pair_problems(va, vb, nodes_a, nodes_b):
            key, _, rest = line.removeprefix(f"{both}: ").partition(": ")
            qualified = f"{both}: {va.qualify(key)}: {rest}"
            if qualified not in out:
                out.append(qualified)
    return out


def parse_checked(raw: Any, source: str = "<memory>", environ: Mapping[str, str] | None = None) -> Resolved:
    """The config validated, its nodes resolved and cross-checked: ConfigError otherwise."""
    loaded = parse_resolved(raw, source, environ)
    check_config(*loaded)
    return loaded


def load_checked(path: str | os.PathLike[str], environ: Mapping[str, str] | None = None) -> Resolved:
    """A config file validated, its nodes resolved and cross-checked: ConfigError otherwise."""
    loaded = load_resolved(path, environ)
    check_config(*loaded)
    return loaded


__all__ = [
    "SIGNAL_BITS",
    "boot_problems",
    "check_config",
    "cob_id_problems",
    "config_notes",
    "config_problems",
    "config_warnings",
    "eds_problems",
    "load_checked",
    "pair_of_networks",
    "pair_problems",
    "parse_checked",
    "protocol_problems",
]
