"""The device-side timeouts a take-over of a hot-standby pair can outlast (``takeover_warnings``,
every ``check`` through ``config_warnings``): one warning per timeout shorter than what this
gateway's worst take-over (``checks.pair.takeover_worst_ms``) leaves the device without the
frame it watches, naming the node, the object, both times and the fix; and one when no node
talks unasked (a standby then cannot tell the active's death from its own cut cable: no
take-over can be promised). The worst take-over counts how rarely the devices talk.

What a take-over leaves a device without, counted from the old active gateway's last frame of
the kind to the new one's first (``worst`` the worst take-over, which already counts the one
heartbeat period the old gateway may have been about to send):

==========================================  ================================  ==================
device timeout                              its time                          without the frame
==========================================  ================================  ==================
life guarding (the node guarded)            guard_time_ms x life_time_factor  worst
heartbeat consumer of the logical master    1016h (boot step, else EDS/DCF)   worst
  (1016h, producer ``master.node_id``)
AP05 external heartbeat fed by RPDOs        5F09h:01 (``external_heartbeat``)  worst + the node's
  (5F09h:02 = 0, AP05 manual 5.5.4)                                           keep-alive period
AP05 external heartbeat fed by SYNC         5F09h:01                          worst + two SYNC
  (5F09h:02 = 1)                                                              periods
RPDO deadline monitoring (CiA 301: the      140xh:05 of an RPDO the device    worst + one round
  event timer of an RPDO; EMCY 8250h)       consumes (boot step, else         of the keep-alive
                                            EDS/DCF)                          (each RPDO in turn)
SYNC-driven outputs (an RPDO of             1006h, the communication cycle    worst + two SYNC
  transmission type 0..240) on a device     period the device is given        periods
  that is given a SYNC cycle to expect
==========================================  ================================  ==================

The keep-alive comes once at the take-over (an adopted node's at once), then every period;
the new active gateway's SYNC keeps its own phase, so its first SYNC may come one period after
it became active. A SYNC another master produces (``master.sync_external``) does not pause.

Imports: checks.pair (the worst take-over), canopen.cia301, canopen.objref, config (types),
device.resolved (types), eds.pdos (the EDS/DCF value). No I/O.
"""

from __future__ import annotations

from canopen_gateway.canopen.cia301 import OBJ_HEARTBEAT_CONSUMER, PDO_COMM_BASE
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.checks.pair import takeover_worst_ms
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.eds.pdos import default_value

Warning = tuple[str, str]

#: CiA 301 7.5.2.6: the communication cycle period in us (0: none)
OBJ_COMM_CYCLE = ObjRef(0x1006, 0x00)
#: CiA 301 7.5.2.35: transmission types 0..240 are synchronous (acted on at the next SYNC)
SYNC_TYPES = range(0, 241)


def takeover_warnings(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[Warning]:
    """``(key path, text)`` per device timeout a take-over by this gateway can outlast, and one
    when no node talks unasked (no take-over can be promised)."""
    pair = cfg.master.redundancy
    if pair is None:
        return []
    worst = takeover_worst_ms(cfg, nodes)  # counts how rarely the devices talk
    if worst is None:
        return [(
            "nodes",
            "no node talks unasked (supervision: heartbeat with heartbeat_ms): a standby cannot "
            "tell the active gateway's death from its own cut cable and takes the bus over only "
            "once it hears a frame again; give at least one node a heartbeat producer "
            "(heartbeat_ms), the faster the sooner the take-over",
        )]  # fmt: skip
    how = (
        f"the worst take-over by this gateway (redundancy.node_id {pair.node_id}), {worst} ms = "
        f"takeover_ms (or two heartbeat_ms + the devices' shortest heartbeat) + its slot + one "
        f"heartbeat_ms"
    )
    out: list[Warning] = []
    for i, n in enumerate(cfg.nodes):
        rn = nodes.get(n.name)
        if rn is None:
            continue
        s = rn.settings
        if s.supervision == "guarding" and s.life_time_ms < worst:
            out.append((
                f"nodes[{i}].guard_time_ms",
                f"node {n.name}: node guarding life time {s.guard_time_ms} ms x "
                f"{s.life_time_factor} = {s.life_time_ms} ms is shorter than {how}: its life "
                f"guarding expires at a take-over; make guard_time_ms x life_time_factor at "
                f"least {worst} ms, or supervise it by heartbeat",
            ))  # fmt: skip
        out += _consumers(cfg, i, rn, worst, how)
        out += _external_heartbeat(cfg, i, rn, worst, how)
        out += _rpdo_deadlines(i, rn, worst, how)
        out += _sync_outputs(cfg, i, rn, worst, how)
    return out


def _written(rn: ResolvedNode, obj: ObjRef) -> tuple[int, str] | None:
    """The last boot step writing ``obj``: its value and config key ("" for the profile's own)."""
    if rn.cfg.configure:
        for step in reversed(rn.boot_steps):
            if step.object == obj and isinstance(step.value, int):
                return step.value, step.source
    return None


def _held(rn: ResolvedNode, obj: ObjRef) -> tuple[int, str | None] | None:
    """The value the device holds in ``obj`` once configured and where it comes from: the last
    boot step writing it (``_written``), else (None) its EDS/DCF value; None when neither says."""
    written = _written(rn, obj)
    if written is not None:
        return written
    value = default_value(rn.lp.od_var(obj), rn.cfg.node_id)
    return (value, None) if isinstance(value, int) and not isinstance(value, bool) else None


def _where(i: int, rn: ResolvedNode, source: str | None) -> tuple[str, str]:
    """(key path, what sets it) of a value ``_held`` found."""
    if source is None:
        return f"nodes[{i}].{'eds' if rn.cfg.eds else 'profile'}", f"its {rn.lp.eds_path.name}"
    if not source:
        return f"nodes[{i}]", f"the boot configuration of profile {rn.lp.family}"
    return f"nodes[{i}].{source}", f"{source}"


def _consumers(cfg: Config, i: int, rn: ResolvedNode, worst: int, how: str) -> list[Warning]:
    """1016h sub-indices whose consumer watches the logical master's heartbeat."""
    entry = rn.lp.od.get(OBJ_HEARTBEAT_CONSUMER)
    subs = set(getattr(entry, "subindices", {}) or {}) - {0}
    subs |= {st.object.sub for st in rn.boot_steps if st.object.index == OBJ_HEARTBEAT_CONSUMER}
    out: list[Warning] = []
    name = rn.cfg.name
    for sub in sorted(subs):
        obj = ObjRef(OBJ_HEARTBEAT_CONSUMER, sub)
        held = _held(rn, obj)
        if held is None:
            continue
        value, source = held
        consumer_ms, producer = value & 0xFFFF, (value >> 16) & 0x7F
        if producer != cfg.master.node_id or not 0 < consumer_ms < worst:
            continue
        if source is not None and source.startswith("sdo"):
            out.append((
                f"nodes[{i}].sdo",
                f"node {name}: boot step {obj} sets its consumer of the logical master's "
                f"heartbeat (node {producer}) to {consumer_ms} ms, shorter than {how}: it "
                f"reports a heartbeat loss at a take-over; write a consumer time of at least "
                f"{worst} ms",
            ))  # fmt: skip
            continue
        key, what = _where(i, rn, source)
        out.append((
            key,
            f"node {name}: {what} sets {obj}, its consumer of the logical master's heartbeat "
            f"(node {producer}), to {consumer_ms} ms, shorter than {how}: it reports a "
            f"heartbeat loss at a take-over; write a consumer time of at least {worst} ms "
            f"(nodes[].sdo: {obj} = 0x{(producer << 16) | worst:08X})",
        ))  # fmt: skip
    return out


def _external_heartbeat(cfg: Config, i: int, rn: ResolvedNode, worst: int, how: str) -> list[Warning]:
    """The AP05's external heartbeat (5F09h): RPDOs or SYNC must come within its interval."""
    eh = rn.cfg.external_heartbeat
    spec = rn.lp.profile.features.get("external_heartbeat")
    if eh is None or spec is None:
        return []
    obj = ObjRef.parse(spec["interval"])
    if eh.source == "rpdo":
        period = round(rn.settings.keepalive_ms)
        feed = f"RPDOs (the keep-alive every {period} ms)"
        plus = "one keep-alive period"
    elif cfg.master.sync_period_ms and not cfg.master.sync_external:
        period = round(2 * cfg.master.sync_period_ms)
        feed, plus = f"SYNC (every {cfg.master.sync_period_ms:g} ms)", "two SYNC periods"
    else:
        return []  # another master's SYNC does not pause at a take-over
    gap = worst + period
    if eh.interval_ms >= gap:
        return []
    return [(
        f"nodes[{i}].external_heartbeat.interval_ms",
        f"node {rn.cfg.name}: external heartbeat ({obj}) {eh.interval_ms} ms, fed by {feed}, "
        f"is shorter than the {gap} ms a take-over can leave it without one ({how}, + {plus}): "
        f"the device goes pre-operational at a take-over; make external_heartbeat.interval_ms "
        f"at least {gap} ms",
    )]  # fmt: skip


def _rpdo_deadlines(i: int, rn: ResolvedNode, worst: int, how: str) -> list[Warning]:
    """An RPDO's event timer is the device's deadline for it (CiA 301 7.2.2.5: RPDO timeout,
    EMCY 8250h)."""
    _, rpdos = rn.lp.profile.layout(rn.cfg.pdo_variant if rn.lp.profile.pdo_variants else None)
    keepalive = round(rn.settings.keepalive_ms)
    gap = worst + len(rpdos) * keepalive
    plus = f", + one round of the keep-alive: {len(rpdos)} x {keepalive} ms" if keepalive else ""
    out: list[Warning] = []
    for p in rpdos:
        obj = ObjRef(PDO_COMM_BASE["rpdo"] + p.number - 1, 0x05)
        held = _held(rn, obj)
        if held is None or not 0 < held[0] < gap:
            continue
        key, what = _where(i, rn, held[1])
        out.append((
            key,
            f"node {rn.cfg.name}: {what} sets the event timer of RPDO{p.number} ({obj}), the "
            f"device's deadline for it, to {held[0]} ms, shorter than the {gap} ms a take-over "
            f"can leave it without that RPDO ({how}{plus}): the device reports an RPDO timeout "
            f"(EMCY 8250h) at a take-over; make it 0 (no deadline) or at least {gap} ms",
        ))  # fmt: skip
    return out


def _sync_outputs(cfg: Config, i: int, rn: ResolvedNode, worst: int, how: str) -> list[Warning]:
    """SYNC-driven RPDOs of a device given a SYNC cycle (1006h) to expect."""
    period = cfg.master.sync_period_ms
    if not period or cfg.master.sync_external:
        return []
    held = _held(rn, OBJ_COMM_CYCLE)
    if held is None or held[0] <= 0:
        return []
    cycle_ms = held[0] / 1000.0
    gap = round(worst + 2 * period)
    _, rpdos = rn.lp.profile.layout(rn.cfg.pdo_variant if rn.lp.profile.pdo_variants else None)
    out: list[Warning] = []
    for p in rpdos:
        obj = ObjRef(PDO_COMM_BASE["rpdo"] + p.number - 1, 0x02)
        written = _written(rn, obj)
        kind = written[0] if written is not None else p.transmission_type
        if kind is None:
            kind = default_value(rn.lp.od_var(obj), rn.cfg.node_id)
        if kind not in SYNC_TYPES or cycle_ms >= gap:
            continue
        key, what = _where(i, rn, held[1])
        out.append((
            key,
            f"node {rn.cfg.name}: RPDO{p.number} is SYNC-driven (transmission type {kind}, "
            f"{obj}) and {what} sets {OBJ_COMM_CYCLE}, the SYNC cycle the device expects, to "
            f"{held[0]} us: a take-over leaves it {gap} ms without SYNC ({how}, + two SYNC "
            f"periods of {period:g} ms): its outputs wait and a device that supervises the "
            f"SYNC reports it lost; let the device tolerate {gap} ms without SYNC, or make "
            f"RPDO{p.number} asynchronous (transmission type 254 or 255)",
        ))  # fmt: skip
    return out
