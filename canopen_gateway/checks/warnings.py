"""What runs but may not do what is meant (``config_warnings``), and what the gateway will not
check (``config_notes``): ``canopen-gateway check`` prints them after its summary, as warnings
and notes, one ``(key path, text naming the node)`` each; they never stop a start.

Warnings, each network's (``Config.network_view``, its keys under its ``networks[k].``): a
device's own TPDO and RPDO on one COB-ID; an enabled SYNC-driven TPDO (transmission type
0..240) without a SYNC producer (``master.sync_period_ms`` 0 and no ``master.sync_external``);
a node whose PDOs map nothing (no process data: named with the objects its file marks
PDO-mappable); node guarding over socketcand (no remote frames); a COB-ID the node's EDS/DCF
writes absolute that is another node's pre-defined one; a DCF whose ``[DeviceComissioning]
NodeID`` is not the node id it is used at; in a hot-standby pair, each device timeout the
gateway's worst take-over can outlast (``checks.takeover``).

Notes: a part of a device's identity (1018h) its file gives nothing to compare with
(``profiles.identity_check``).

Imports: config, device.resolved, bus.cob_id_uses, eds (load_eds, pdos, file_cob_ids),
profiles (identity_check), checks.takeover.
"""

from __future__ import annotations

from canopen_gateway.bus.cob_id_uses import clashes, gateway_uses, loops_back
from canopen_gateway.checks.takeover import takeover_warnings
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.eds import EdsError, load_eds
from canopen_gateway.eds.file_cob_ids import dcf_node_id, foreign_cob_ids, foreign_text
from canopen_gateway.eds.pdos import mappable_objects, object_name, od_var
from canopen_gateway.profiles import identity_check

Problem = tuple[str, str]


#: socketcand's ASCII protocol (rawmode ``< send ID LEN DATA >``) has no remote frame: a guarding
#: RTR arrives as a data frame of no data, which no device answers
GUARDING_OVER_SOCKETCAND = (
    "node guarding needs remote frames (RTR), which socketcand's protocol cannot carry: the node "
    "would be counted lost; supervise it by heartbeat (supervision: heartbeat) or use another "
    "CAN interface"
)


def config_warnings(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """What runs but may not do what is meant (see the module docstring), each network's."""
    return [
        (view.qualify(k), m) for view in cfg.network_views() for k, m in _bus_warnings(view, nodes)
    ]


def _bus_warnings(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """``config_warnings`` of one network's config."""
    out: list[Problem] = []
    resolved = nodes
    for first, later in clashes(gateway_uses(cfg, resolved)):
        if loops_back(first, later):
            out.append(
                (
                    later.key,
                    f"node {later.node}: COB-ID 0x{later.cob_id:03X} of {later} is also "
                    f"{first}: the device sends and receives on one COB-ID; a write of its "
                    "RPDO would be a second sender on it",
                )
            )
    sync = cfg.master.sync_period_ms or cfg.master.sync_external
    for i, n in enumerate(cfg.nodes):
        rn = resolved.get(n.name)
        if rn is None:
            continue
        key = f"nodes[{i}]"
        if rn.sync_tpdos and not sync:
            out.append((key, f"node {n.name}: {sync_wait_text(rn)}"))
        if not any(s.transport == "pdo" for s in rn.lp.profile.signals):
            out.append((f"{key}.tpdo", f"node {n.name}: {no_process_data_text(rn)}"))
        if rn.settings.supervision == "guarding" and cfg.can.interface == "socketcand":
            out.append((f"{key}.supervision", f"node {n.name}: {GUARDING_OVER_SOCKETCAND}"))
        try:
            eds = load_eds(rn.lp.eds_path)
        except EdsError:
            continue
        file = rn.lp.eds_path.name
        own = dcf_node_id(eds)
        if own is not None and own[0] != n.node_id:
            out.append(
                (
                    f"{key}.node_id",
                    f"node {n.name}: node id {n.node_id}, but {file} [{own[1].section}] line "
                    f"{own[1].line} says NodeID {own[0]}: the file was written for node "
                    f"{own[0]}; COB-IDs it writes absolute are that node's",
                )
            )
        for c, function, owner in foreign_cob_ids(eds, n.node_id):
            out.append((key, f"node {n.name}: {c.where(file)}: {foreign_text(c, function, owner)}"))
    return out + takeover_warnings(cfg, resolved)


def sync_wait_text(rn: ResolvedNode) -> str:
    """``TPDO2 is SYNC-driven (transmission type 1) but nothing produces SYNC ...``"""
    pdos = ", ".join(f"TPDO{n}" for n in rn.sync_tpdos)
    verb, them = ("is", "it") if len(rn.sync_tpdos) == 1 else ("are", "them")
    return (
        f"{pdos} {verb} SYNC-driven (transmission type 0..240) but no SYNC producer is "
        f"configured: the device never sends {them}; set master.sync_period_ms, or "
        "master.sync_external: true when another master sends SYNC"
    )


#: how many PDO-mappable objects the warning of a node without process data names
MAPPABLE_NAMED = 8


def no_process_data_text(rn: ResolvedNode) -> str:
    """``serves no process data: map one with `tpdo:` ...``, naming the objects its file marks
    PDO-mappable (a node whose PDOs map nothing: Modbus input register 0 says bad)."""
    lp = rn.lp
    file = lp.eds_path.name
    head = (
        "serves no process data: map one with `tpdo:` (its PDOs map nothing, so its Modbus "
        "quality, input register 0, says bad)"
    )
    objs = mappable_objects(lp.od, "tpdo")
    application = [o for o in objs if o.index >= 0x2000]  # before 1001h, the SDO COB-IDs...
    objs = application or objs
    if not objs:
        return (
            f"{head}; but {file} marks no object PDO-mappable (PDOMapping=1): where the "
            "device's manual says it maps one, correct the file; else read its objects by SDO "
            "(canopen-gateway sdo read, or signals with transport: sdo in an overlay profile)"
        )
    named = ", ".join(f"{o} ({object_name(lp.od, o)})" for o in objs[:MAPPABLE_NAMED])
    more = f" and {len(objs) - MAPPABLE_NAMED} more (canopen-gateway eds show {file})" if len(objs) > MAPPABLE_NAMED else ""  # fmt: skip
    # the example maps what the device sends (ro, rwr: an input), not an output it receives
    # (rww: 6040h controlword), and sends it on change (255: no SYNC needed)
    sent = [o for o in objs if getattr(od_var(lp.od, o), "access_type", "") in ("ro", "rwr")] or objs
    example = f'tpdo: {{1: {{mapping: ["{sent[0]}"], transmission: 255}}}}'
    return f"{head}, e.g. `{example}`; PDO-mappable in {file}: {named}{more}"


def config_notes(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Problem]:
    """What the gateway will not check (``check`` prints them as notes): a part of a device's
    identity (1018h) its file gives nothing to compare with (``profiles.identity_check``)."""
    out: list[Problem] = []
    for i, n in enumerate(cfg.nodes):
        rn = nodes.get(n.name)
        if rn is None or not n.identity_check:
            continue
        key = cfg.qualify(f"nodes[{i}].identity_check")  # networks[k].nodes[j] in that form
        out += [(key, f"node {n.name}: {text}") for text in identity_check(rn.lp).not_checked]
    return out
