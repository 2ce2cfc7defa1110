"""The checks of the two configs of a hot-standby pair (``check -c A -c B``, docs/redundancy.md):
``pair_problems(a, b, nodes_a, nodes_b)``, one line per disagreement naming both files and the
key path: the same CAN bus, logical master, nodes (their device description and profile by
content) and Modbus layout; both with ``master.redundancy``, distinct own ids, ``peer_node_id``
naming the other; a bus two processes can share (not ``interface: virtual``).

It also refuses time slots (CiA 302-2: priority x 1F90h:04 + node id x 1F90h:05) that do not
follow the priority order.

``takeover_worst_ms(cfg, nodes)``: this gateway's worst take-over, as the role machine runs it
(counting how rarely the devices talk), which the device timeouts are held against
(``checks.takeover``).

Imports: bus.pair.member (the pair's times), config (types), device.resolved (types). No I/O
but reading the device files to compare.
"""

from __future__ import annotations

import hashlib
from typing import Any

from canopen_gateway.bus.pair.member import pair_timing, talk_period_s
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode

#: what the two configs of a pair must agree on besides the nodes: the bus, the logical master
#: (every ``master.*`` but this gateway's own ``redundancy``), the CiA 302-2 slots (1F90h:04,
#: 1F90h:05, the same on both or the negotiation is not one), the register layout a PLC reads.
PAIR_SHARED_CAN = ("interface", "channel", "bitrate")
PAIR_SHARED_SLOTS = ("priority_slot_ms", "device_slot_ms")
PAIR_SHARED_MODBUS = ("layout", "gateway_unit_id", "flat_unit_id", "flat_stride", "word_order")
#: python-can interfaces whose bus lives in one process: two gateway processes never meet on it
PRIVATE_BUSES = {"virtual": "each process's own in-process bus"}
#: what to use instead (docs/redundancy.md, "A pair on one machine")
SHARED_BUS_HINT = (
    "use the plant's CAN interface (socketcan, pcan, kvaser, ...), or on one machine a bus "
    "shared by processes: python-can-remote (interface: remote, channel: ws://127.0.0.1:PORT/) "
    "or socketcand (interface: socketcand, host, port, channel)"
)


def takeover_worst_ms(cfg: Config, nodes: dict[str, ResolvedNode] | None = None) -> int | None:
    """The longest the logical master may be silent when this gateway takes over from a dead
    active one (``PairTiming.worst_takeover_s``, the times the role machine runs on): the
    standby negotiates once the master was silent for ``takeover_ms`` and it heard a frame of a
    device after two heartbeats (the devices that talk unasked talk again within their
    shortest heartbeat, ``nodes``' ``heartbeat_ms``), then claims at the end of its CiA 302-2
    time slot (priority x ``priority_slot_ms`` + node id x ``device_slot_ms``); plus the
    heartbeat the old active one may have been about to send (one ``heartbeat_ms``). Without
    ``nodes`` the devices are taken to talk every ``heartbeat_ms``. None: not in a pair, or no
    node talks unasked (no take-over can be promised: ``checks.takeover`` says so)."""
    pair = cfg.master.redundancy
    if pair is None:
        return None
    if nodes is None:
        talk_s: float | None = cfg.master.heartbeat_ms / 1000.0
    else:
        talk_s = talk_period_s(rn.settings for n in cfg.nodes if (rn := nodes.get(n.name)))
    worst = pair_timing(cfg, talk_s).worst_takeover_s(pair.priority, pair.node_id)
    return None if worst is None else round(1000 * worst)


def _differences(key: str, a: Any, b: Any) -> list[tuple[str, Any, Any]]:
    """``(key path, value in a, value in b)`` of each leaf where two dumped sections differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out: list[tuple[str, Any, Any]] = []
        for k in [*a, *(k for k in b if k not in a)]:
            out += _differences(f"{key}.{k}" if key else str(k), a.get(k), b.get(k))
        return out
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in _differences(f"{key}[{i}]", x, y)]
    return [] if a == b else [(key, a, b)]


def _digest(path: Any) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def pair_problems(
    a: Config,
    b: Config,
    nodes_a: dict[str, ResolvedNode],
    nodes_b: dict[str, ResolvedNode],
) -> list[str]:
    """One line per disagreement of the two configs of a pair, each naming both files and the
    key path (each config checked on its own already)."""
    both = f"{a.source}, {b.source}"
    out: list[str] = []

    def differ(key: str, va: Any, vb: Any) -> None:
        out.append(f"{both}: {key}: {va!r} in {a.source}, {vb!r} in {b.source}: a pair must agree")

    for k in PAIR_SHARED_CAN:
        va, vb = getattr(a.can, k), getattr(b.can, k)
        if va != vb:
            differ(f"can.{k}", va, vb)
    for cfg in (a, b) if a.can.interface != b.can.interface else (a,):
        private = PRIVATE_BUSES.get(cfg.can.interface)
        if private is not None:
            out.append(
                f"{both}: can.interface: {cfg.can.interface!r} in {cfg.source} is {private}: the "
                f"two gateways of a pair would never hear each other (both would master the "
                f"devices); {SHARED_BUS_HINT}"
            )
    master_a = a.master.model_dump(exclude={"redundancy"})
    master_b = b.master.model_dump(exclude={"redundancy"})
    for key, va, vb in _differences("master", master_a, master_b):
        differ(key, va, vb)
    pa, pb = a.master.redundancy, b.master.redundancy
    for cfg, pair in ((a, pa), (b, pb)):
        if pair is None:
            out.append(f"{both}: master.redundancy: missing in {cfg.source}: both configs of a pair need it")
    if pa is not None and pb is not None:
        for k in PAIR_SHARED_SLOTS:
            va, vb = getattr(pa, k), getattr(pb, k)
            if va != vb:
                differ(f"master.redundancy.{k}", va, vb)
        if pa.node_id == pb.node_id:
            out.append(f"{both}: master.redundancy.node_id: {pa.node_id} in both: each gateway needs its own id")
        else:
            out += _slot_order(a, b)
        for cfg, pair, other in ((a, pa, pb), (b, pb, pa)):
            if pair.peer_node_id is not None and pair.peer_node_id != other.node_id:
                out.append(
                    f"{both}: master.redundancy.peer_node_id: {pair.peer_node_id} in {cfg.source}, "
                    f"but the other gateway's master.redundancy.node_id is {other.node_id}"
                )
    if a.modbus.enabled and b.modbus.enabled:
        for k in PAIR_SHARED_MODBUS:
            va, vb = getattr(a.modbus, k), getattr(b.modbus, k)
            if va != vb:
                differ(f"modbus.{k}", va, vb)
    out += _pair_node_problems(a, b, nodes_a, nodes_b)
    return out


def _slot_order(a: Config, b: Config) -> list[str]:
    """The CiA 302-2 time slots (priority x 1F90h:04 + node id x 1F90h:05) must follow the
    priority order (lower priority first, then lower node id): a third-party master, and a
    negotiation between the two, decide by which slot ends first."""
    pa, pb = a.master.redundancy, b.master.redundancy
    assert pa is not None and pb is not None
    ranked = sorted(((a.source, pa), (b.source, pb)), key=lambda x: (x[1].priority, x[1].node_id))
    (bf, better), (wf, worse) = ranked
    slot_better = better.priority * better.priority_slot_ms + better.node_id * better.device_slot_ms
    slot_worse = worse.priority * worse.priority_slot_ms + worse.node_id * worse.device_slot_ms
    if slot_better < slot_worse:
        return []
    steps = worse.priority - better.priority  # the priority slots between them (0: same priority)
    fix = (
        f"a priority_slot_ms over {(better.node_id - worse.node_id) * better.device_slot_ms / steps:g} ms"
        if steps else "a device_slot_ms over 0 ms"
    )
    return [
        f"{a.source}, {b.source}: master.redundancy: the CiA 302-2 time slots do not follow the "
        f"priority order: {bf} (priority {better.priority}, node_id {better.node_id}) waits "
        f"{slot_better:g} ms, {wf} (priority {worse.priority}, node_id {worse.node_id}) "
        f"{slot_worse:g} ms (priority x priority_slot_ms + node_id x device_slot_ms): the worse "
        f"one would claim first; give the better one the lower node_id, or {fix}"
    ]


def _pair_node_problems(
    a: Config, b: Config, nodes_a: dict[str, ResolvedNode], nodes_b: dict[str, ResolvedNode]
) -> list[str]:
    """The same nodes by name, each with the same settings, device description and profile."""
    both = f"{a.source}, {b.source}"
    out: list[str] = []
    index_b = {n.name: j for j, n in enumerate(b.nodes)}
    names_a = {n.name for n in a.nodes}
    for i, n in enumerate(a.nodes):
        j = index_b.get(n.name)
        if j is None:
            out.append(f"{both}: nodes[{i}]: node {n.name} only in {a.source}")
            continue
        m = b.nodes[j]
        where = f"nodes[{i}]" if i == j else f"nodes[{i}] ({n.name}, nodes[{j}] in {b.source})"
        dump_a = n.model_dump(exclude={"profile", "eds"})
        dump_b = m.model_dump(exclude={"profile", "eds"})
        for key, va, vb in _differences("", dump_a, dump_b):
            out.append(f"{both}: {where}.{key}: {va!r} in {a.source}, {vb!r} in {b.source}: a pair must agree")
        ra, rb = nodes_a.get(n.name), nodes_b.get(n.name)
        if ra is None or rb is None:
            continue  # its profile does not load: said by each file's own check
        key = f"{where}.{'eds' if n.eds else 'profile'}"
        if _digest(ra.lp.eds_path) != _digest(rb.lp.eds_path):
            out.append(
                f"{both}: {key}: the device descriptions differ "
                f"({ra.lp.eds_path} in {a.source}, {rb.lp.eds_path} in {b.source})"
            )
        if ra.lp.profile.model_dump() != rb.lp.profile.model_dump():
            out.append(
                f"{both}: {key}: the profiles differ ({ra.lp.path} in {a.source}, {rb.lp.path} in {b.source})"
            )
    for j, m in enumerate(b.nodes):
        if m.name not in names_a:
            out.append(f"{both}: nodes[{j}]: node {m.name} only in {b.source}")
    return out
