"""Which gateway of a hot-standby pair is the bus's NMT master: CiA 302-2 NMT flying master.

Two gateways run the same config on one bus. Both stand for one *logical* master
(``master.node_id``: the heartbeat the devices consume, NMT, SYNC, RPDOs, the SDO client); each
has an id of its own in the pair (``master.redundancy.node_id``) under which it makes its claims.
One of them is **active** (it does everything a master does), the other **standby** (it only
listens, and sends its own heartbeat and its detection requests). This module decides the role.

Rule 1: every decision about the role lives here, and the role changes are the table
``TRANSITIONS`` the code reads (as h11's ``_state.py``). A change the table does not define
raises ``PairError`` (our own misuse); a frame that means nothing in the current role is
counted in ``ignored``.
Rule 2: nothing here does I/O or reads a clock. The caller reports what it heard
(``on_frame(cob_id, data, now)``), calls ``poll(now)`` at ``next_deadline_s()``, and does what
the returned actions say (``Send`` a frame; ``RoleChanged`` tells it to start or stop mastering).

The frames (CiA 302-2, NMT flying master; no payload unless said):

=====  ==========================================  ========================================
COB-ID  name                                        here
=====  ==========================================  ========================================
71h    active master response ``[priority, id]``   sent when a gateway claims, on every
                                                    73h/72h/76h it hears while active, and
                                                    again every ``claim_period_s``
72h    master negotiation request                  sent by a gateway that starts to negotiate
73h    active master request                       sent once at start (the detection request)
76h    force negotiation                           heard only: answered with a 71h
=====  ==========================================  ========================================

The roles, and the table (``*`` any claim, ``<`` a claim that wins against ours by (priority,
node id): lower priority first, then lower node id; ``>`` one that loses)::

    role         heard / timer                  next         does
    listening    logical heartbeat, 71h *       standby      (the active master is there)
    listening    72h                            negotiating  waits its time slot
    listening    detection time over            negotiating  sends 72h, waits its time slot
    negotiating  logical heartbeat, 71h *       standby      (someone is active: no fail-back)
    negotiating  time slot over                 active       sends 71h
    standby      72h                            negotiating  waits its time slot
    standby      active master silent           negotiating  sends 72h, waits its time slot
    active       71h <                          standby      goes silent at once
    active       stalled (no event for takeover_s)  standby  goes silent at once
    active       71h >, 72h, 73h, 76h           active       answers 71h

An active gateway that was stalled (its process frozen, its machine starved) for longer than the
take-over time stands by at once when it runs again: the other gateway may have taken over
meanwhile, and two masters must never act on the bus. If nobody did, it negotiates again like
any standby. A gateway that comes back joins as standby whatever its priority (no fail-back: a change of
master is never made while one is working). Two actives that hear each other (after a partition
or a frozen process) are resolved by (priority, node id) within one claim period.

The time slot is CiA 302-2's: ``priority * priority_slot_s + node_id * device_slot_s``
(1F90h:04, 1F90h:05); the defaults here are shorter than 1F90h's (1500 ms, 10 ms) so that a
take-over fits in a second.

Imports: gateway.bus.transitions (the table's rows), gateway.cia301 (the heartbeat's COB-ID) and
the standard library.
Must not import python-can, asyncio, logging, config or any northbound module.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Literal, NamedTuple

from gateway.bus.transitions import transition_table
from gateway.cia301 import COB_NMT_EC as COB_HEARTBEAT  # heartbeat, + node id

# CiA 302-2 (NMT flying master): the COB-IDs of its services
COB_ACTIVE_MASTER_RESPONSE = 0x71  # [priority, node id]
COB_NEGOTIATION_REQUEST = 0x72
COB_ACTIVE_MASTER_REQUEST = 0x73
COB_FORCE_NEGOTIATION = 0x76
FLYING_MASTER_COB_IDS = frozenset(
    {
        COB_ACTIVE_MASTER_RESPONSE,
        COB_NEGOTIATION_REQUEST,
        COB_ACTIVE_MASTER_REQUEST,
        COB_FORCE_NEGOTIATION,
    }
)


class Role(StrEnum):
    LISTENING = "listening"  # just started: is there an active master?
    NEGOTIATING = "negotiating"  # no active master heard: waiting for its time slot
    STANDBY = "standby"  # another gateway is active: listen only
    ACTIVE = "active"  # this gateway is the bus's NMT master


class Heard(StrEnum):
    """What moves the role (the columns of ``TRANSITIONS``)."""

    LOGICAL_HEARTBEAT = "logical heartbeat"  # 700h + master.node_id from another gateway
    BETTER_CLAIM = "71h that wins"
    WORSE_CLAIM = "71h that loses"
    NEGOTIATION = "72h"
    REQUEST = "73h"
    FORCE = "76h"
    DETECTION_OVER = "detection time over"
    SLOT_OVER = "time slot over"
    ACTIVE_SILENT = "active master silent"
    STALLED = "this gateway stalled"  # no event for longer than the take-over time


_L, _N, _S, _A = Role.LISTENING, Role.NEGOTIATING, Role.STANDBY, Role.ACTIVE
_H = Heard
#: (role, heard) -> next role: every role change, written as the rows of the module docstring's
#: table (from these roles, on these, to)
TRANSITIONS: dict[tuple[Role, Heard], Role] = transition_table(
    ((_L, _N), (_H.LOGICAL_HEARTBEAT, _H.BETTER_CLAIM, _H.WORSE_CLAIM), _S),
    ((_L, _S), (_H.NEGOTIATION,), _N),
    ((_L,), (_H.DETECTION_OVER,), _N),
    ((_N,), (_H.SLOT_OVER,), _A),
    ((_S,), (_H.ACTIVE_SILENT,), _N),
    ((_A,), (_H.BETTER_CLAIM, _H.STALLED), _S),
)
#: (role, heard) pairs that keep the role but are answered (the active master's 71h)
ANSWERED: frozenset[tuple[Role, Heard]] = frozenset(
    {(_A, _H.WORSE_CLAIM), (_A, _H.NEGOTIATION), (_A, _H.REQUEST), (_A, _H.FORCE)}
)
#: (role, heard) pairs that only tell the standby the active master is alive
ALIVE: frozenset[tuple[Role, Heard]] = frozenset(
    {(_S, _H.LOGICAL_HEARTBEAT), (_S, _H.BETTER_CLAIM), (_S, _H.WORSE_CLAIM)}
)


class PairError(RuntimeError):
    """Our own misuse of the machine: a role change the table does not define."""


class Send(NamedTuple):
    """Send this frame (11-bit ``cob_id``, ``data``)."""

    kind: Literal["send"]
    cob_id: int
    data: bytes


class RoleChanged(NamedTuple):
    """The role changed: start (``active``) or stop mastering the bus; ``reason`` for the log."""

    kind: Literal["role"]
    role: Role
    previous: Role
    reason: str


Action = Send | RoleChanged


@dataclass(frozen=True)
class PairTiming:
    """The times of the pair, in seconds (config ``master.redundancy``)."""

    takeover_s: float  # the active master's heartbeat missing this long: it is gone
    detect_s: float  # at start: listen this long for an active master
    claim_period_s: float  # the active master repeats its 71h this often
    priority_slot_s: float = 0.2  # CiA 302-2 1F90h:04, per priority level
    device_slot_s: float = 0.002  # CiA 302-2 1F90h:05, per node id

    def slot_s(self, priority: int, node_id: int) -> float:
        """CiA 302-2 time slot: how long a candidate waits before it claims."""
        return priority * self.priority_slot_s + node_id * self.device_slot_s


@dataclass(frozen=True)
class Claim:
    """A 71h heard from another gateway, and when."""

    priority: int
    node_id: int
    at_s: float


def wins(a: tuple[int, int], b: tuple[int, int]) -> bool:
    """True when claim ``a`` = (priority, node id) wins against ``b``: lower first."""
    return a < b


class FlyingMaster:
    """The role of one gateway of the pair, fed ``(frame, now)`` and ``poll(now)``."""

    def __init__(self, *, node_id: int, priority: int, master_node_id: int, timing: PairTiming):
        if not 1 <= node_id <= 127 or not 0 <= priority <= 255:
            raise ValueError(f"pair id {node_id} / priority {priority} out of range")
        self.node_id = node_id
        self.priority = priority
        self.master_node_id = master_node_id
        self.timing = timing
        self.role = Role.LISTENING
        self.started = False
        #: the last 71h of another gateway (the peer), if any was heard
        self.peer: Claim | None = None
        #: the last time the active master was heard (its heartbeat or its 71h)
        self.active_heard_s: float | None = None
        self.ignored = 0  # frames that meant nothing in the role (our own echo among them)
        self.takeovers = 0  # standby -> active through a negotiation
        self.negotiations = 0
        self.stalls = 0  # active -> standby because this gateway stalled
        self._deadline_s = 0.0

    # ------------------------------------------------------------------ queries

    @property
    def active(self) -> bool:
        return self.role is Role.ACTIVE

    def next_deadline_s(self) -> float | None:
        """When ``poll`` must run next (``None`` before ``start``)."""
        return self._deadline_s if self.started else None

    def claim_frame(self) -> Send:
        return Send("send", COB_ACTIVE_MASTER_RESPONSE, bytes((self.priority, self.node_id)))

    # ------------------------------------------------------------------ events

    def start(self, now: float) -> list[Action]:
        """Start listening: one active master request (73h), then wait ``detect_s``."""
        if self.started:
            raise PairError("the pair machine is started once")
        self.started = True
        self._deadline_s = now + self.timing.detect_s
        return [Send("send", COB_ACTIVE_MASTER_REQUEST, b"")]

    def on_frame(self, cob_id: int, data: bytes, now: float) -> list[Action]:
        """A frame heard on the bus (only the flying-master ids and the logical heartbeat
        concern this machine; others are not passed here)."""
        heard = self._classify(cob_id, data, now)
        if heard is None:
            self.ignored += 1
            return []
        return self._fire(heard, now)

    def on_stall(self, now: float) -> list[Action]:
        """The caller found that this gateway did not run for longer than the take-over time
        (its process frozen, its machine starved): an active one stands by at once."""
        if self.role is not Role.ACTIVE:
            return []
        self.stalls += 1
        return self._fire(Heard.STALLED, now)

    def poll(self, now: float) -> list[Action]:
        """The deadline of the role has come (or not yet: then nothing happens)."""
        if not self.started or now < self._deadline_s:
            return []
        if self.role is Role.ACTIVE:
            self._deadline_s = now + self.timing.claim_period_s
            return [self.claim_frame()]
        heard = {
            Role.LISTENING: Heard.DETECTION_OVER,
            Role.NEGOTIATING: Heard.SLOT_OVER,
            Role.STANDBY: Heard.ACTIVE_SILENT,
        }[self.role]
        return self._fire(heard, now)

    # ------------------------------------------------------------------ inside


    def _classify(self, cob_id: int, data: bytes, now: float) -> Heard | None:
        if cob_id == COB_HEARTBEAT + self.master_node_id:
            # while active it may be our own frame echoed by the bus: not evidence of anyone
            return None if self.role is Role.ACTIVE else Heard.LOGICAL_HEARTBEAT
        if cob_id == COB_ACTIVE_MASTER_RESPONSE:
            if len(data) < 2 or data[1] == self.node_id:
                return None  # malformed, or our own claim echoed
            self.peer = Claim(data[0], data[1], now)
            theirs = (data[0], data[1])
            ours = (self.priority, self.node_id)
            return Heard.BETTER_CLAIM if wins(theirs, ours) else Heard.WORSE_CLAIM
        return {
            COB_NEGOTIATION_REQUEST: Heard.NEGOTIATION,
            COB_ACTIVE_MASTER_REQUEST: Heard.REQUEST,
            COB_FORCE_NEGOTIATION: Heard.FORCE,
        }.get(cob_id)

    def _fire(self, heard: Heard, now: float) -> list[Action]:
        key = (self.role, heard)
        if heard in (Heard.LOGICAL_HEARTBEAT, Heard.BETTER_CLAIM, Heard.WORSE_CLAIM):
            self.active_heard_s = now
        if key in ALIVE:
            self._deadline_s = now + self.timing.takeover_s
            return []
        if key in ANSWERED:
            self._deadline_s = now + self.timing.claim_period_s
            return [self.claim_frame()]
        nxt = TRANSITIONS.get(key)
        if nxt is None:
            if heard in (Heard.DETECTION_OVER, Heard.SLOT_OVER, Heard.ACTIVE_SILENT):
                raise PairError(f"no transition for {heard.value} in {self.role.value}")
            self.ignored += 1
            return []
        return self._enter(nxt, heard, now)

    def _enter(self, role: Role, heard: Heard, now: float) -> list[Action]:
        previous, self.role = self.role, role
        actions: list[Action] = []
        if role is Role.STANDBY:
            self._deadline_s = now + self.timing.takeover_s
            reason = _standby_reason(heard, self.peer)
        elif role is Role.NEGOTIATING:
            self.negotiations += 1
            self._deadline_s = now + self.timing.slot_s(self.priority, self.node_id)
            if heard is not Heard.NEGOTIATION:
                actions.append(Send("send", COB_NEGOTIATION_REQUEST, b""))
            reason = {
                Heard.NEGOTIATION: "another gateway negotiates (72h)",
                Heard.DETECTION_OVER: "no active master heard at start",
                Heard.ACTIVE_SILENT: (
                    f"the active master was silent for {self.timing.takeover_s * 1000:.0f} ms"
                ),
            }[heard]
        else:  # ACTIVE
            if previous is Role.NEGOTIATING and self.active_heard_s is not None:
                self.takeovers += 1
            self._deadline_s = now + self.timing.claim_period_s
            actions.append(self.claim_frame())
            reason = "no other claim within the time slot"
        return [RoleChanged("role", role, previous, reason), *actions]


def _standby_reason(heard: Heard, peer: Claim | None) -> str:
    if heard is Heard.STALLED:
        return "this gateway did not run for longer than the take-over time: the other may be active"
    if heard is Heard.LOGICAL_HEARTBEAT:
        return "the logical master's heartbeat is heard"
    who = f"priority {peer.priority}, node {peer.node_id}" if peer else "another gateway"
    if heard is Heard.BETTER_CLAIM:
        return f"an active master that wins ({who}) is heard"
    return f"an active master ({who}) is heard: no fail-back"
