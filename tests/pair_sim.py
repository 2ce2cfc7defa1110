"""A hot-standby pair on a fake bus and a fake clock, for the generated fault sequences
(``tests/unit/test_pair_sequences.py``): two members, each the real role machine
(``FlyingMaster``) and the real nodes (``Node``, built listening as a pair's member is), joined
by the glue ``bus/pair/member.py`` and ``side.py`` are on a running gateway (a role change
starts or stops mastering, takes the nodes over or stands them by; the master's frames pass one
gate), and scripted devices (heartbeat producers, SDO servers, NMT slaves; device 3 also
consumes the logical master's heartbeat and falls pre-operational when it misses it).

Faults, each of one member unless said: ``cut`` (it hears nothing, nothing it sends arrives),
``mute`` (it hears, nothing it sends arrives, its driver unaware), ``unplug`` (its bus down:
the driver says so), ``kill`` / ``restart``, ``freeze`` / ``thaw`` (it does not run, then runs
on with its old state), ``split`` (the bus in two halves: A with device 1, B with device 3, the AP05 with either),
``lose`` (its next frames reach no one), ``stop`` (SIGTERM: a planned hand-over), ``step`` (its wall clock steps: frame times are what
the driver makes of a socketcand server's stamps, ``BusDriver.stamp``), the operator's NMT
command and a PLC write (through the member the operator or PLC picks: a set point or the
control word of the AP05 at node 5, whose RPDO1 and RPDO2 both carry the control word).

What the rule of docs/redundancy.md forbids is recorded as it happens (``violations``): an NMT
command that is not the operator's, or an SDO download, reaching a device that is OPERATIONAL;
an NMT start of a node the operator put pre-operational or stopped (the command reached it) by
a member that knew it (heard the command and was not out since); two members' logical
heartbeats reaching one device more than ``ALLOW_S`` after the last fault; a write
acknowledged by a member whose frames have not reached the bus for longer than ``ALLOW_S``
while the other masters it; an output of the AP05 changed but by a new write (an RPDO's content
reaching the operational device, the guarding bit aside, that no write since its current
content made: an older write's or a member's defaults); after a take-over, an RPDO the new
active member sends before its first write that is not what was last sent in it, when the new
member sent or heard that frame (the model sees what it knew).

Imports: canopen_gateway.bus.pair, canopen_gateway.bus.node, canopen_gateway.bus.driver (``stamp``), canopen_gateway.canopen,
tests.helpers, tests.unit.test_node (the scripted device's SDO and NMT).
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.events import Send as NodeSend
from canopen_gateway.bus.node import listening
from canopen_gateway.bus.node.node import Node
from canopen_gateway.bus.node.outputs import OutputImage
from canopen_gateway.bus.node.parts import build_node
from canopen_gateway.bus.pair.flying_master import (
    FLYING_MASTER_COB_IDS,
    FlyingMaster,
    Notice,
    PairTiming,
    Role,
    RoleChanged,
    Send,
)
from canopen_gateway.canopen.cia301 import NMT_COMMANDS
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.errors import NodeNotOperational
from canopen_gateway.image import NodeImage
from canopen_gateway.profiles import expected_identity
from tests.helpers import make_config, resolved
from tests.unit.test_node import Device

LOGICAL = 100
HB_S = 0.1
DEVICE_HB_S = 0.2
TIMING = PairTiming(takeover_s=0.3, detect_s=0.3, heartbeat_s=HB_S, talk_s=DEVICE_HB_S)
#: after a fault (and after its repair) the pair may take this long to settle: the worst
#: take-over (max(300, 200 + 200) + 404 + 100 ms) and the slower of a stand-down
ALLOW_S = 1.2
MEMBERS = {"A": (101, 0, 102, "a"), "B": (102, 1, 101, "b")}  # id, priority, peer, half
DEVICES = {1: "a", 3: "b", 5: "b"}  # node id -> the half of a split bus it is on
#: the AP05 (manual 5.3.1.2): its RPDOs are the outputs a PLC writes
OUTPUTS = 5
#: device 3's consumer of the logical heartbeat (1016h): it falls pre-operational without it
CONSUMER_S = 1.5
WALL0 = 1.7e9  # the relay's wall clock at time 0

_CFG = make_config(
    [
        {"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 200},
        {"name": "enc", "node_id": 3, "profile": "posi_plus", "heartbeat_ms": 200},
        {"name": "display", "node_id": OUTPUTS, "profile": "ap05", "heartbeat_ms": 200},
    ],
    master={"node_id": LOGICAL, "heartbeat_ms": 100, "heartbeat_timeout_multiple": 3},
)
_RESOLVED = resolved(_CFG)
_NAMES = {n.node_id: n.name for n in _CFG.nodes}


def _decoder() -> OutputImage:
    """The AP05's RPDOs read as a device does (``content``: the guarding bit masked)."""
    rn = _RESOLVED["display"]
    image = NodeImage("display", OUTPUTS, rn.lp.family, [s.name for s in rn.lp.profile.signals])
    node = build_node(rn, image).node
    gb = rn.settings.guarding_bit
    assert gb is not None and node.control_signal is not None
    return OutputImage("display", node.rpdos, control=(node.control_signal, gb.control_bit))


@dataclass
class Dev:
    """A device: the scripted SDO server / NMT slave, its heartbeat, its half of the bus."""

    node_id: int
    half: str
    script: Device
    consumer_s: float | None = None
    last_logical_s: float = 0.0
    operator: str | None = None  # the operator's last NMT command to it
    operator_arrived: bool = False  # ...and it reached the device (else it took no effect)
    #: the members that heard that command and have not been out since (they know it)
    knowers: set[str] = field(default_factory=set)
    #: the AP05's outputs: RPDO number -> its content as received (the guarding bit masked) and
    #: the write whose content it is (0: none)
    rpdo: dict[int, tuple[list[Any], int]] = field(default_factory=dict)
    #: RPDO number -> when its content last changed
    rpdo_since: dict[int, float] = field(default_factory=dict)

    @property
    def state(self) -> NmtState:
        return self.script.state


@dataclass
class Member:
    name: str
    pair_id: int
    priority: int
    peer_id: int
    half: str
    fm: FlyingMaster
    nodes: dict[int, Node]
    mastering: bool = False
    up: bool = True
    frozen_at: float | None = None
    last_run_s: float = 0.0
    last_rx: tuple[float, float] | None = None  # (stamp, its monotonic time)
    next_beat_s: float = 0.0
    next_logical_s: float = 0.0
    wall_step_s: float = 0.0
    refused: int = 0  # writes refused (not active)


@dataclass
class Sim:
    now: float = 0.0
    members: dict[str, Member] = field(default_factory=dict)
    devices: dict[int, Dev] = field(default_factory=dict)
    cut: set[str] = field(default_factory=set)
    mute: set[str] = field(default_factory=set)
    unplugged: set[str] = field(default_factory=set)
    split: bool = False
    lose: dict[str, int] = field(default_factory=dict)
    #: when each member's frames last reached the bus, and when they stopped (a fault)
    silent_since: dict[str, float] = field(default_factory=dict)
    last_fault_s: float = 0.0
    violations: list[str] = field(default_factory=list)
    #: (time, sender, device) of each logical heartbeat that reached a device
    logical: list[tuple[float, str, int]] = field(default_factory=list)
    log: list[tuple[float, str, int, bytes, bool]] = field(default_factory=list)
    #: the PLC's writes acknowledged: RPDO number -> (write, the RPDO's content after it)
    written: dict[int, list[tuple[int, list[Any]]]] = field(default_factory=dict)
    writes: int = 0
    #: RPDO number -> the content last sent in it (the guarding bit masked), its sender and the
    #: members it reached
    last_rpdo: dict[int, tuple[list[Any], str, set[str]]] = field(default_factory=dict)
    #: after a take-over: member -> RPDO number -> what was last sent in it (that member sent or
    #: heard it), until the member's first write
    expect: dict[str, dict[int, list[Any]]] = field(default_factory=dict)
    #: RPDO number -> the members that sent or heard the content the AP05 holds now (its sender
    #: and whom that frame, or a later one of the same content, reached)
    knew: dict[int, set[str]] = field(default_factory=dict)
    #: (time, member, previous role, role, fresh) of every role change
    roles_log: list[tuple[float, str, Role, Role, bool]] = field(default_factory=list)
    #: outputs a member changed back to content it last heard, having missed the frame of the
    #: newer one without any sign of it (see ``_output_frame``): the documented limit
    unnoticed: list[str] = field(default_factory=list)
    decoder: OutputImage = field(default_factory=_decoder)
    _queue: list[tuple[float, int, Callable[[], None]]] = field(default_factory=list)
    _seq: itertools.count = field(default_factory=itertools.count)  # type: ignore[type-arg]

    # ------------------------------------------------------------------ building
    def add_member(self, name: str) -> Member:
        pair_id, priority, peer, half = MEMBERS[name]
        fm = FlyingMaster(node_id=pair_id, priority=priority, master_node_id=LOGICAL,
                          timing=TIMING, peer_id=peer)  # fmt: skip
        nodes = {}
        for n in _CFG.nodes:
            rn = _RESOLVED[n.name]
            image = NodeImage(n.name, n.node_id, rn.lp.family, [s.name for s in rn.lp.profile.signals])
            nodes[n.node_id] = build_node(rn, image, listening=True).node
        m = Member(name, pair_id, priority, peer, half, fm, nodes, last_run_s=self.now,
                   next_beat_s=self.now + 2 * HB_S, next_logical_s=self.now)  # fmt: skip
        self.members[name] = m
        for dev in self.devices.values():
            dev.knowers.discard(name)
        self.cut.discard(name)
        self.mute.discard(name)
        self.unplugged.discard(name)
        self._act(m, fm.start(self.now))
        for node in nodes.values():
            self._node(m, node, node.start(self.now, probe=False))
        return m

    def add_devices(self) -> None:
        for node_id, half in DEVICES.items():
            rn = _RESOLVED[_NAMES[node_id]]
            ident = {(o.index, o.sub): v for o, v in expected_identity(rn.lp)}
            script = Device(node_id, rn.lp.profile.device_type or 0, identity=ident)
            dev = Dev(node_id, half, script, CONSUMER_S if node_id == 3 else None, self.now)
            self.devices[node_id] = dev
            self.at(self.now + 0.05 * node_id, lambda d=dev: self._boot(d))

    @classmethod
    def settled(cls) -> Sim:
        """A active with the devices configured, B standby: the start of every sequence."""
        sim = cls()
        sim.add_devices()
        sim.add_member("A")
        sim.run(4.0)
        sim.add_member("B")
        sim.run(3.0)
        assert (sim.members["A"].fm.role, sim.members["B"].fm.role) == (Role.ACTIVE, Role.STANDBY), sim.roles()
        assert all(d.state == NmtState.OPERATIONAL for d in sim.devices.values())
        sim.violations.clear()
        sim.last_fault_s = sim.now
        return sim

    def roles(self) -> dict[str, str]:
        return {n: str(m.fm.role) if m.up else "dead" for n, m in self.members.items()}

    # ------------------------------------------------------------------ the clock
    def at(self, t: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self._queue, (t, next(self._seq), fn))

    def run(self, seconds: float) -> None:
        end = self.now + seconds
        for _ in range(2_000_000):
            t, fn = self._next()
            if t > end:
                self.now = end
                return
            self.now = max(self.now, t)
            fn()
        raise AssertionError(f"{self.now:.3f}: events without end (a timer that never moves)")

    def _next(self) -> tuple[float, Callable[[], None]]:
        best: tuple[float, Callable[[], None]] = (math.inf, lambda: None)
        if self._queue:
            t, _, _ = self._queue[0]
            best = (t, lambda: heapq.heappop(self._queue)[2]())
        for m in self.members.values():
            if not m.up or m.frozen_at is not None:
                continue
            for t, fn in self._member_timers(m):
                if t < best[0]:
                    best = (t, fn)
        return best

    def _member_timers(self, m: Member) -> list[tuple[float, Callable[[], None]]]:
        out: list[tuple[float, Callable[[], None]]] = [
            (m.next_beat_s, lambda: self._beat(m)),
            (m.next_logical_s, lambda: self._logical(m)),
        ]
        d = m.fm.next_deadline_s()
        if d is not None:
            out.append((max(d, self.now), lambda: self._act(m, m.fm.poll(self.now))))
        for node in m.nodes.values():
            nd = node.next_deadline()
            if nd is not None:
                at = nd if nd > self.now else math.nextafter(self.now, math.inf)
                out.append((at, lambda node=node: self._node(m, node, node.tick(self.now))))
        return out

    # ------------------------------------------------------------------ a member's glue
    def _ran(self, m: Member) -> None:
        """``PairMember.check``: a member that did not run for longer than the take-over time."""
        if self.now - m.last_run_s > TIMING.takeover_s:
            self._act(m, m.fm.on_stall(self.now))
        m.last_run_s = self.now

    def _stamp(self, m: Member, sent_s: float) -> float:
        """What the member's driver makes of a frame the relay stamped at ``sent_s``."""
        fake = SimpleNamespace(_burst=(self.now, WALL0 + self.now + m.wall_step_s), mono=lambda: self.now)
        return float(BusDriver.stamp(fake, WALL0 + sent_s))  # type: ignore[arg-type]

    def _beat(self, m: Member) -> None:
        self._ran(m)
        m.next_beat_s = self.now + HB_S
        alive = any(n.alive for n in m.nodes.values())
        self._act(m, m.fm.on_hearing(self.now, m.last_rx[0] if m.last_rx else None, alive))
        if m.fm.role is not Role.DUPLICATE:
            self._send(m, 0x700 + m.pair_id, bytes((m.fm.own_state,)))

    def _logical(self, m: Member) -> None:
        self._ran(m)
        m.next_logical_s = self.now + HB_S
        if m.mastering:
            self._send(m, 0x700 + LOGICAL, b"\x05")

    def _act(self, m: Member, actions: list[Any]) -> None:
        for a in actions:
            if isinstance(a, Send):
                self._send(m, a.cob_id, a.data)
            elif isinstance(a, RoleChanged):
                self._role(m, a)
            else:
                assert isinstance(a, Notice)

    def _role(self, m: Member, change: RoleChanged) -> None:
        self.roles_log.append((self.now, m.name, change.previous, change.role, change.fresh))
        if change.role is Role.ACTIVE:
            m.mastering = True
            self.expect[m.name] = {
                n: content for n, (content, sender, reached) in self.last_rpdo.items()
                if m.name == sender or m.name in reached
            }  # fmt: skip
            self._send(m, 0x700 + LOGICAL, b"\x05")
            for node in m.nodes.values():
                self._node(m, node, node.take_over(self.now, m.fm.master_heard))
        elif change.previous is Role.ACTIVE or change.fresh:
            self.expect.pop(m.name, None)
            if change.fresh:  # out: what it heard of the operator is forgotten
                for dev in self.devices.values():
                    dev.knowers.discard(m.name)
            m.mastering = False
            for node in m.nodes.values():
                self._node(m, node, node.stand_by(self.now, change.fresh))

    def _node(self, m: Member, node: Node, outs: list[Any]) -> None:
        for o in outs:
            if isinstance(o, NodeSend) and m.mastering and not o.rtr:
                self._send(m, o.cob_id, o.data)

    # ------------------------------------------------------------------ the bus
    def _send(self, m: Member, cob_id: int, data: bytes, operator: bool = False) -> None:
        if not m.up or m.frozen_at is not None or m.name in self.unplugged:
            return
        lost = m.name in self.cut or m.name in self.mute
        if not lost and self.lose.get(m.name, 0) > 0:
            self.lose[m.name] -= 1
            lost = True
        self.log.append((self.now, m.name, cob_id, data, not lost))
        reached = set() if lost else {o.name for o in self.members.values() if o is not m and self._reaches(m.half, o)}
        if cob_id in self.decoder.cob_ids:
            self._rpdo_sent(m, cob_id, data, reached)
        if lost:
            self.silent_since.setdefault(m.name, self.now)
            return
        self.silent_since.pop(m.name, None)
        sent = self.now
        for other in self.members.values():
            if other.name in reached:
                self.at(sent + 0.0005, lambda o=other: self._receive(o, m.name, cob_id, data, sent))
        for dev in self.devices.values():
            if not self.split or dev.half == m.half:
                self.at(sent + 0.0005, lambda d=dev: self._device_frame(d, m.name, cob_id, data, operator))

    def _reaches(self, half: str, m: Member) -> bool:
        return (
            m.up and m.frozen_at is None and m.name not in self.cut and m.name not in self.unplugged
            and (not self.split or m.half == half)
        )  # fmt: skip

    def _device_send(self, dev: Dev, cob_id: int, data: bytes) -> None:
        sent = self.now
        self.log.append((sent, f"dev{dev.node_id}", cob_id, data, True))
        for m in self.members.values():
            if self._reaches(dev.half, m):
                self.at(sent + 0.0005, lambda m=m: self._receive(m, "dev", cob_id, data, sent))

    def _receive(self, m: Member, sender: str, cob_id: int, data: bytes, sent_s: float) -> None:
        if not self._reaches(m.half, m) or not m.up:
            return
        self._ran(m)
        t = self._stamp(m, sent_s)
        m.last_rx = (t, self.now)
        if cob_id in FLYING_MASTER_COB_IDS or cob_id in (0x700 + LOGICAL, 0x700 + m.pair_id):
            met = m.fm.meetings
            self._act(m, m.fm.on_frame(cob_id, data, t))
            if m.fm.meetings != met and m.mastering:  # ``PairSide._on_pair_frame``
                for node in m.nodes.values():
                    listening.another_master(node, t)
        elif cob_id == 0x700 + m.peer_id:
            self._act(m, m.fm.on_peer_heartbeat(data, t))
        elif cob_id in self.decoder.cob_ids:  # ``PairSide._on_rpdo_heard``: the other's outputs
            node = m.nodes[OUTPUTS]
            self._node(m, node, node.on_rpdo_heard(cob_id, data, WALL0 + self.now, t))
        elif cob_id - 0x700 in m.nodes and data:
            node = m.nodes[cob_id - 0x700]
            self._node(m, node, node.on_nmt_ec(data[0], t))
        elif cob_id - 0x580 in m.nodes:
            node = m.nodes[cob_id - 0x580]
            self._node(m, node, node.on_sdo_response(data, t))
        elif cob_id == 0x000 and not m.mastering and len(data) >= 2:
            command = next((c for c, b in NMT_COMMANDS.items() if b == data[0]), None)
            for node in m.nodes.values():
                if command is not None and data[1] in (0, node.node_id):
                    node.on_nmt_command(command)
        elif cob_id - 0x600 in m.nodes and not m.mastering:
            node = m.nodes[cob_id - 0x600]
            self._node(m, node, listening.on_sdo_heard(node, t))

    # ------------------------------------------------------------------ the devices
    def _rpdo_content(self, cob_id: int, data: bytes) -> tuple[int, list[Any]]:
        codec = next(c for c in self.decoder.rpdos if c.cob_id == cob_id)
        self.decoder.heard(cob_id, data, self.now)
        return codec.number, self.decoder.content(codec.number)

    def _output_frame(self, dev: Dev, sender: str, cob_id: int, data: bytes) -> None:
        """An RPDO the operational AP05 processes: its output changes only by a new write.

        One case is the documented limit, not a violation: a standby that missed the frame of
        the content the device holds (its own stub cut for an instant, no time to notice) and
        had no role change since but the take-over from which it sends: nothing told it that
        its image is behind (docs/redundancy.md)."""
        n, content = self._rpdo_content(cob_id, data)
        last = self.last_rpdo.get(n)
        told = {sender} | (last[2] if last is not None and last[0] == content and last[1] == sender else set())
        current = dev.rpdo.get(n)
        if current is not None and current[0] == content:
            self.knew.setdefault(n, set()).update(told)  # a repeat: more members know it now
            return
        made = [w for w, c in self.written.get(n, []) if c == content and (current is None or w > current[1])]
        if current is not None and not made:
            text = (f"{self.now:.3f}: {sender} changed RPDO{n} of node {dev.node_id} from {current[0]} to "
                    f"{content}: no write since made it")  # fmt: skip
            since = dev.rpdo_since.get(n, 0.0)
            changes = [(prev, role, fresh) for t, who, prev, role, fresh in self.roles_log if who == sender and t >= since]
            unnoticed = sender not in self.knew.get(n, set()) and changes == [(Role.STANDBY, Role.ACTIVE, False)]
            (self.unnoticed if unnoticed else self.violations).append(text)
        dev.rpdo[n] = (content, max(made, default=0 if current is None else current[1]))
        dev.rpdo_since[n] = self.now
        self.knew[n] = set(told)

    def _rpdo_sent(self, m: Member, cob_id: int, data: bytes, reached: set[str]) -> None:
        """An RPDO a member sends: after a take-over, before its first write, it carries what
        was last sent in it (that the member sent or heard)."""
        n, content = self._rpdo_content(cob_id, data)
        expect = self.expect.get(m.name)
        was = expect.pop(n, None) if expect is not None else None
        if was is not None and was != content:
            self.violations.append(
                f"{self.now:.3f}: {m.name} took over and sent RPDO{n} {content}; {was} was last sent in it"
            )
        self.last_rpdo[n] = (content, m.name, reached)

    def _boot(self, dev: Dev) -> None:
        dev.script.boot()
        dev.rpdo.clear()
        dev.last_logical_s = self.now
        self._device_send(dev, 0x700 + dev.node_id, b"\x00")
        self.at(self.now + DEVICE_HB_S, lambda: self._device_beat(dev))

    def _device_beat(self, dev: Dev) -> None:
        if dev.consumer_s is not None and self.now - dev.last_logical_s > dev.consumer_s:
            if dev.state == NmtState.OPERATIONAL:
                dev.script.state = NmtState.PRE_OPERATIONAL  # its error behaviour (1029h)
        self._device_send(dev, 0x700 + dev.node_id, bytes((int(dev.state),)))
        self.at(self.now + DEVICE_HB_S, lambda: self._device_beat(dev))

    def _device_frame(self, dev: Dev, sender: str, cob_id: int, data: bytes, operator: bool) -> None:
        if cob_id == 0x700 + LOGICAL:
            dev.last_logical_s = self.now
            self.logical.append((self.now, sender, dev.node_id))
            return
        before = dev.state
        if cob_id == 0x000 and len(data) >= 2 and data[1] in (0, dev.node_id):
            self._check_nmt(dev, sender, data[0], before, operator)
        elif cob_id == 0x600 + dev.node_id and data and data[0] >> 5 == 1 and before == NmtState.OPERATIONAL:
            self.violations.append(f"{self.now:.3f}: {sender} sent an SDO download to operational node {dev.node_id}")
        elif dev.node_id == OUTPUTS and cob_id in self.decoder.cob_ids and before == NmtState.OPERATIONAL:
            self._output_frame(dev, sender, cob_id, data)
        for delay, cob, answer in dev.script.on_frame(NodeSend(cob_id, data)):
            self.at(self.now + delay, lambda c=cob, a=answer: self._device_send(dev, c, a))

    def _check_nmt(self, dev: Dev, sender: str, command: int, before: NmtState, operator: bool) -> None:
        if operator:
            dev.operator_arrived = True  # its intent is recorded when sent (``operator_nmt``)
            return
        if before == NmtState.OPERATIONAL:
            self.violations.append(f"{self.now:.3f}: {sender} sent NMT {command:02X}h to operational node {dev.node_id}")
        elif command == 0x01 and dev.operator is not None and dev.operator_arrived and sender in dev.knowers:
            self.violations.append(
                f"{self.now:.3f}: {sender} started node {dev.node_id} the operator put {dev.operator}"
            )

    # ------------------------------------------------------------------ what an operator, a PLC does
    def operator_nmt(self, name: str, command: str, node_id: int) -> bool:
        """The operator's NMT command through member ``name`` (refused unless it masters)."""
        m = self.members[name]
        if not m.up or m.frozen_at is not None or not m.mastering:
            return False
        m.nodes[node_id].on_nmt_command(command)
        self._send(m, 0x000, bytes((NMT_COMMANDS[command], node_id)), operator=True)
        knowers = {name} | {o.name for o in self.members.values() if o is not m and self._reaches(m.half, o)}
        if name in self.cut or name in self.mute:
            knowers = {name}
        dev = self.devices[node_id]
        dev.knowers = knowers
        dev.operator = {"start": None, "preop": "preop", "stop": "stop"}.get(command, dev.operator)
        dev.operator_arrived = False  # a command that reaches no device takes no effect (as with one gateway)
        return True

    def plc_write(self, name: str, signal: str = "set_point1") -> bool:
        """A PLC write of ``signal`` of the AP05 through member ``name`` (a value no write
        made before): acknowledged only while it masters the bus and the node is operational."""
        m = self.members[name]
        if not m.up or m.frozen_at is not None:
            return False
        if not m.mastering:
            m.refused += 1
            return False
        node = m.nodes[OUTPUTS]
        k = self.writes + 1
        value = ((k % 127) + 1) << 9 if signal == "control_word" else 1000 + k  # bit 8 the gateway's
        try:
            outs = node.write_outputs({None: {signal: value}}, self.now)
        except NodeNotOperational:
            return False
        self.writes = k
        for codec in node.rpdos:
            self.written.setdefault(codec.number, []).append((k, node.outputs.content(codec.number)))
        self.expect.pop(name, None)
        since = self.silent_since.get(name)
        # another master it hears (its half of a split bus): it could have known
        near = {d for d, dev in self.devices.items() if not self.split or dev.half == m.half}
        others = {s for _, s, d in self.logical if d in near and s != name}
        if since is not None and self.now - since > ALLOW_S and others:
            self.violations.append(
                f"{self.now:.3f}: {name} acknowledged a write while its frames reached no one since "
                f"{since:.3f} and {sorted(others)} mastered the bus"
            )
        self._node(m, node, outs)
        return True

    def stop(self, name: str) -> None:
        """SIGTERM: ``PairMember.hand_over`` (an active member whose peer stands by stops
        mastering and says so in its own heartbeat), then the process ends."""
        m = self.members[name]
        if m.up and m.frozen_at is None and m.fm.peer_role(self.now) == "standby":
            self._act(m, m.fm.hand_over(self.now))
            if not m.fm.active:
                self._send(m, 0x700 + m.pair_id, bytes((m.fm.own_state,)))
        m.up = False

    # ------------------------------------------------------------------ faults
    def fault(self) -> None:
        self.last_fault_s = self.now

    def check_masters(self) -> None:
        """Two members' logical heartbeats reached one device within 250 ms, longer than
        ``ALLOW_S`` after the last fault or repair (a split bus has a master per half)."""
        self.logical = [x for x in self.logical if x[0] >= self.now - 0.25]
        for node_id in self.devices:
            senders = {s for _, s, d in self.logical if d == node_id}
            if len(senders) > 1 and self.now - self.last_fault_s > ALLOW_S:
                self.violations.append(f"{self.now:.3f}: two masters for node {node_id}: {sorted(senders)}")

    def masters(self, within_s: float = 0.25) -> set[str]:
        return {s for t, s, _ in self.logical if t >= self.now - within_s}
