"""Which gateway of a hot-standby pair is the bus's NMT master: CiA 302-2 NMT flying master.

Two gateways run the same config on one bus. Both stand for one *logical* master
(``master.node_id``: the heartbeat the devices consume, NMT, SYNC, RPDOs, the SDO client); each
has an id of its own in the pair (``master.redundancy.node_id``) under which it makes its claims.
One of them is **active** (it does everything a master does), the other **standby** (it only
listens, and sends its own heartbeat). This module decides the role.

Rule 1: every role change is a row of ``TRANSITIONS``; what a role does without changing is a
row of ``DOES``. A timer event the tables do not define raises ``PairError`` (our own misuse); a
frame that means nothing in the current role is counted in ``ignored``.
Rule 2: nothing here does I/O or reads a clock. The caller reports what it heard
(``on_frame(cob_id, data, now)``), whether it hears the bus at all (``on_hearing(now,
last_frame_s, nodes_alive)``: when the driver last received any frame) and whether its bus is
open (``on_link(up, now)``), calls ``poll(now)`` at ``next_deadline_s()``, and does what the
returned actions say (``Send`` a frame; ``RoleChanged`` tells it to start or stop mastering;
``Notice`` is a line for the log).

The frames (CiA 302-2, NMT flying master; the emotas stack's behaviour is the reference): 71h
active master response ``[priority, id]``, sent once at a claim (the end of a time slot) and per
73h heard while active; 72h negotiation request (starts every capable device's time slot); 73h
active master request, sent when a gateway starts listening; 75h detect master-capable devices,
answered by one 74h ``[priority, id]``; 76h force negotiation, sent by the active one every
``detect_cycle_s`` (1F90h:06) and when it meets another master (an active one hearing it
negotiates again).

The roles (``*`` any claim, ``<`` a claim that wins against ours by (priority, node id): lower
priority first, then lower node id; ``>`` one that loses; *traffic*: a frame of anyone but this
gateway, after the active master's next heartbeat was due: the last frame's time)::

    role         heard / timer                        next         does
    listening    logical heartbeat, 71h *, 76h        standby      (an active master is there)
    listening    72h                                  negotiating  waits its time slot
    listening    detection time over                  negotiating  sends 72h, waits its slot
    negotiating  logical heartbeat, 71h *             standby      (someone is active)
    negotiating  time slot over                       active       sends 71h
    standby      72h                                  negotiating  waits its time slot
    standby      master silent, traffic heard         negotiating  sends 72h, waits its slot
    standby      master silent, no traffic twice      isolated     sends nothing (cut off)
    standby      master silent, no traffic yet        standby      waits takeover_s more, looks
                                                                   every heartbeat / 4
    active       71h < in its own slot                standby      goes silent at once
    active       stalled (no event for takeover_s)    standby      goes silent at once
    active       another master, after a deaf spell   standby      (never a fail-back onto it)
    active       no traffic and no node alive         isolated     goes silent at once
    l/n/s/a      bus down                             isolated     goes silent at once
    isolated     traffic heard, bus open              listening    sends 73h (joins as standby)
    l/n/s/i      71h or heartbeat of our own pair id  duplicate    sends nothing, ever

    active       73h                                  active       answers one 71h
    active       72h                                  active       waits its slot, then 71h
    active       76h                                  active       sends 72h, its slot, 71h
    active       71h > or < outside a slot, the       active       forces a negotiation: 76h,
                 logical heartbeat of another sender               72h, its slot, 71h
                                                                   (once per detect cycle)
    active       detect cycle over                    active       sends 76h
    active       our own pair id heard                active       keeps the bus, reports it
    l/n/s/a      75h                                  (same)       answers 74h

A gateway that comes back (restarted, or from an outage: isolated) listens first and joins as
standby whatever its priority. An active gateway that heard nothing for ``takeover_s`` is marked
*cut* (``was_cut``): it may have missed a take-over, so when it meets another master it stands
by instead of contesting the bus. A 76h or 72h is never answered with more than one 71h, a 73h
by the active one alone: a negotiation costs a handful of frames.

The time slot is CiA 302-2's: ``priority * priority_slot_s + node_id * device_slot_s``
(1F90h:04, 1F90h:05); the defaults here are shorter than 1F90h's (1500 ms, 10 ms) so that a
take-over fits in a second.

Imports: bus.pair.protocol (its vocabulary), bus.transitions (the table's rows), canopen.cia301 (the heartbeat's COB-ID) and
the standard library.
Must not import python-can, asyncio, logging, config or any northbound module.
"""

from __future__ import annotations

from gateway.bus.pair.protocol import (
    COB_ACTIVE_MASTER_REQUEST,
    COB_ACTIVE_MASTER_RESPONSE,
    COB_CAPABLE_RESPONSE,
    COB_DETECT_CAPABLE,
    COB_FORCE_NEGOTIATION,
    COB_NEGOTIATION_REQUEST,
    FLYING_MASTER_COB_IDS,
    Action,
    Claim,
    Heard,
    Notice,
    PairError,
    PairTiming,
    Role,
    RoleChanged,
    Send,
    wins,
)
from gateway.bus.transitions import transition_table
from gateway.canopen.cia301 import COB_NMT_EC as COB_HEARTBEAT  # heartbeat, + node id

__all__ = [
    "COB_ACTIVE_MASTER_REQUEST",
    "COB_ACTIVE_MASTER_RESPONSE",
    "COB_CAPABLE_RESPONSE",
    "COB_DETECT_CAPABLE",
    "COB_FORCE_NEGOTIATION",
    "COB_HEARTBEAT",
    "COB_NEGOTIATION_REQUEST",
    "DOES",
    "FLYING_MASTER_COB_IDS",
    "TRANSITIONS",
    "Action",
    "Claim",
    "FlyingMaster",
    "Heard",
    "Notice",
    "PairError",
    "PairTiming",
    "Role",
    "RoleChanged",
    "Send",
]

_L, _N, _S, _A, _I, _D = (
    Role.LISTENING, Role.NEGOTIATING, Role.STANDBY, Role.ACTIVE, Role.ISOLATED, Role.DUPLICATE
)  # fmt: skip
_H = Heard
#: (role, heard) -> next role: every role change, the rows of the module docstring's table
TRANSITIONS: dict[tuple[Role, Heard], Role] = transition_table(
    ((_L, _N), (_H.LOGICAL_HEARTBEAT, _H.BETTER_CLAIM, _H.WORSE_CLAIM), _S),
    ((_L,), (_H.FORCE,), _S),
    ((_L, _S), (_H.NEGOTIATION,), _N),
    ((_L,), (_H.DETECTION_OVER,), _N),
    ((_N,), (_H.SLOT_OVER,), _A),
    ((_S,), (_H.ACTIVE_SILENT,), _N),
    ((_A,), (_H.OUTBID, _H.STALLED, _H.MET_AFTER_CUT), _S),
    ((_S, _A), (_H.DEAF,), _I),
    ((_L, _N, _S, _A), (_H.LINK_LOST,), _I),
    ((_I,), (_H.BUS_HEARD,), _L),
    ((_L, _N, _S, _I), (_H.OWN_ID,), _D),
)
#: (role, heard) -> what the role does without changing (a method of ``FlyingMaster``)
DOES: dict[tuple[Role, Heard], str] = {
    **{
        (_S, h): "_alive" for h in (_H.LOGICAL_HEARTBEAT, _H.BETTER_CLAIM, _H.WORSE_CLAIM, _H.FORCE)
    },
    (_S, _H.UNHEARD): "_wait_for_the_bus",
    (_A, _H.REQUEST): "_answer",
    (_A, _H.NEGOTIATION): "_join_slot",
    (_A, _H.FORCE): "_negotiate_again",
    (_A, _H.BETTER_CLAIM): "_force",
    (_A, _H.WORSE_CLAIM): "_force",
    (_A, _H.FOREIGN_LOGICAL): "_force",
    (_A, _H.CLAIM_DUE): "_claim",
    (_A, _H.DETECT_DUE): "_detect",
    (_A, _H.OWN_ID): "_conflict",
    **{(r, _H.DETECT_CAPABLE): "_capable" for r in (_L, _N, _S, _A)},
}
#: heard while active after a deaf spell: another master is there, this one stands by
_MEETINGS = frozenset(
    {_H.BETTER_CLAIM, _H.WORSE_CLAIM, _H.FORCE, _H.NEGOTIATION, _H.FOREIGN_LOGICAL}
)
#: what tells the standby the active master is alive
_ALIVE = frozenset({_H.LOGICAL_HEARTBEAT, _H.BETTER_CLAIM, _H.WORSE_CLAIM, _H.FORCE})
#: what says this gateway was out (its own outage): it comes back as a fresh joiner
_OUTAGES = frozenset(
    {_H.LINK_LOST, _H.DEAF, _H.BUS_HEARD, _H.STALLED, _H.MET_AFTER_CUT, _H.OWN_ID}
)
_TIMERS = frozenset(
    {_H.DETECTION_OVER, _H.SLOT_OVER, _H.ACTIVE_SILENT, _H.DEAF, _H.CLAIM_DUE, _H.DETECT_DUE, _H.UNHEARD}
)


class FlyingMaster:
    """The role of one gateway of the pair, fed ``(frame, now)`` and ``poll(now)``.

    ``echo``: the bus hands this gateway its own frames back (python-can
    ``receive_own_messages``): our own pair id and logical heartbeat heard are then our echo.
    ``peer_id``: the other member's pair id when known: a claim of another id is a third-party
    master, whose own heartbeat then tells the standby it is alive.
    """

    def __init__(
        self,
        *,
        node_id: int,
        priority: int,
        master_node_id: int,
        timing: PairTiming,
        echo: bool = False,
        peer_id: int | None = None,
    ):
        if not 1 <= node_id <= 127 or not 0 <= priority <= 255:
            raise ValueError(f"pair id {node_id} / priority {priority} out of range")
        self.node_id = node_id
        self.priority = priority
        self.master_node_id = master_node_id
        self.timing = timing
        self.echo = echo
        self.peer_id = peer_id
        self.role = Role.LISTENING
        self.started = False
        #: the last 71h of another master, if any was heard
        self.peer: Claim | None = None
        #: the last claim of a master that is not the peer (a third-party CiA 302-2 master)
        self.third_party: Claim | None = None
        #: the last time the active master was heard (its heartbeat, its 71h or 76h)
        self.active_heard_s: float | None = None
        #: the last time anyone but this gateway was heard (a frame, the frame counter moving)
        self.heard_s: float | None = None
        self.link_up = True
        #: heard nothing for takeover_s while active: it may have missed a take-over
        self.was_cut = False
        #: what a device with our own pair id was heard sending (None: nothing)
        self.conflict: str | None = None
        self.ignored = 0  # frames that meant nothing in the role (our own echo among them)
        self.takeovers = 0  # standby -> active through a negotiation
        self.negotiations = 0
        self.stalls = 0  # active -> standby because this gateway stalled
        self.isolations = 0  # -> isolated (bus down, or nothing heard)
        self.duplicates = 0  # frames of another device with our own pair id
        self.forced = 0  # negotiations this gateway forced (76h) on meeting another master
        self._deadline_s: float | None = None  # the role's timer (not the active one's)
        self._claim_s: float | None = None  # while active: the end of its slot, then 71h
        self._detect_s: float | None = None  # while active: the next 76h
        self._forced_s: float | None = None  # when it last forced a negotiation
        #: standby: the master silent, the bus not heard since: until when it waits for a frame
        self._doubt_until_s: float | None = None
        self._listened_s = float("inf")  # when it last began listening

    @property
    def active(self) -> bool:
        return self.role is Role.ACTIVE

    @property
    def master_heard(self) -> bool:
        """An active master was heard since this gateway last began listening (its start, or
        back from an outage): a take-over replaces it (not a first start of the bus)."""
        heard = self.active_heard_s
        return heard is not None and heard >= self._listened_s

    def next_deadline_s(self) -> float | None:
        """When ``poll`` must run next (``None``: no timer in this role)."""
        if not self.started:
            return None
        if self.role is Role.ACTIVE:
            times = [t for t in (self._claim_s, self._detect_s) if t is not None]
            return min(times) if times else None
        return self._deadline_s

    def claim_frame(self) -> Send:
        return Send("send", COB_ACTIVE_MASTER_RESPONSE, bytes((self.priority, self.node_id)))

    def start(self, now: float) -> list[Action]:
        """Start listening: one active master request (73h), then wait ``detect_s``."""
        if self.started:
            raise PairError("the pair machine is started once")
        self.started = True
        self._listened_s = now
        self._deadline_s = now + self.timing.detect_s
        return [Send("send", COB_ACTIVE_MASTER_REQUEST, b"")]

    def on_frame(self, cob_id: int, data: bytes, now: float) -> list[Action]:
        """A frame heard on the bus (the flying-master ids, the logical heartbeat, the
        heartbeats of our own pair id and of a third-party master; others are not passed)."""
        heard = self._classify(cob_id, data, now)
        if heard is None:
            self.ignored += 1
            return []
        self.heard_s = now
        actions: list[Action] = []
        if self.role is Role.ISOLATED and self.link_up:
            actions = self._fire(Heard.BUS_HEARD, now)
        return actions + self._fire(heard, now)

    def on_hearing(
        self, now: float, last_frame_s: float | None, nodes_alive: bool = False
    ) -> list[Action]:
        """The caller's report, every heartbeat period or so: when the driver last received a
        frame of anyone (``last_frame_s``, None: never), and whether any node is alive by its
        own supervision. An isolated gateway that hears the bus again listens; a standby in
        doubt that hears the bus after the master fell silent negotiates; an active one that
        heard nothing for ``takeover_s`` is *cut*, and stands down unless a node is alive."""
        if not self.started:
            return []
        if last_frame_s is not None and (self.heard_s is None or last_frame_s > self.heard_s):
            self.heard_s = last_frame_s
            if self.role is Role.ISOLATED and self.link_up:
                return self._fire(Heard.BUS_HEARD, now)
            if self.role is Role.STANDBY and self._doubt_until_s is not None and self._master_gone():
                return self._fire(Heard.ACTIVE_SILENT, now)
            return []
        if self.role is not Role.ACTIVE or self._heard_within(now):
            return []
        out: list[Action] = []
        if not self.was_cut:
            self.was_cut = True
            text = f"pair: active, and nothing heard for {self._ms(self.timing.takeover_s)}"
            out.append(Notice("notice", "deaf", text))
        if not nodes_alive:
            out += self._fire(Heard.DEAF, now)
        return out

    def on_link(self, up: bool, now: float) -> list[Action]:
        """The bus went down (open failed, connection lost, sends failing) or is open again."""
        self.link_up = up
        if up or not self.started or self.role in (Role.ISOLATED, Role.DUPLICATE):
            return []
        return self._fire(Heard.LINK_LOST, now)

    def on_stall(self, now: float) -> list[Action]:
        """The caller found that this gateway did not run for longer than the take-over time
        (its process frozen, its machine starved): an active one stands by at once."""
        if self.role is not Role.ACTIVE:
            return []
        self.stalls += 1
        return self._fire(Heard.STALLED, now)

    def poll(self, now: float) -> list[Action]:
        """The deadline of the role has come (or not yet: then nothing happens)."""
        if not self.started:
            return []
        if self.role is Role.ACTIVE:
            if self._claim_s is not None and now >= self._claim_s:
                return self._fire(Heard.CLAIM_DUE, now)
            if self._detect_s is not None and now >= self._detect_s:
                return self._fire(Heard.DETECT_DUE, now)
            return []
        if self._deadline_s is None or now < self._deadline_s:
            return []
        if self.role is Role.STANDBY:
            heard = Heard.ACTIVE_SILENT if self._master_gone() else Heard.UNHEARD
            if heard is Heard.UNHEARD and self._doubt_until_s is not None:
                heard = Heard.DEAF if now >= self._doubt_until_s else Heard.UNHEARD
        else:
            heard = {Role.LISTENING: Heard.DETECTION_OVER, Role.NEGOTIATING: Heard.SLOT_OVER}[
                self.role
            ]
        return self._fire(heard, now)

    def _master_gone(self) -> bool:
        """A frame was heard after the active master's next two heartbeats were due: the bus
        is alive and the master silent (a frame before that may precede a cut cable, and one
        late heartbeat must not make a cut look like a dead master)."""
        ref = self.active_heard_s if self.active_heard_s is not None else float("-inf")
        return self.heard_s is not None and self.heard_s > ref + 2 * self.timing.heartbeat

    def _heard_within(self, now: float) -> bool:
        return self.heard_s is not None and now - self.heard_s < self.timing.takeover_s

    @staticmethod
    def _ms(seconds: float) -> str:
        return f"{seconds * 1000:.0f} ms"

    def _classify(self, cob_id: int, data: bytes, now: float) -> Heard | None:
        if cob_id == COB_HEARTBEAT + self.master_node_id:
            if self.role is Role.ACTIVE:  # ours echoed, or another sender of our logical id
                return None if self.echo else Heard.FOREIGN_LOGICAL
            return Heard.LOGICAL_HEARTBEAT
        if cob_id == COB_HEARTBEAT + self.node_id:
            return None if self.echo else self._own_id(f"a heartbeat on 0x{cob_id:03X}")
        third = self.third_party
        if third is not None and cob_id == COB_HEARTBEAT + third.node_id:
            return Heard.LOGICAL_HEARTBEAT  # the third-party master's own heartbeat
        if cob_id == COB_ACTIVE_MASTER_RESPONSE:
            return self._claim_heard(data, now)
        return {
            COB_NEGOTIATION_REQUEST: Heard.NEGOTIATION,
            COB_ACTIVE_MASTER_REQUEST: Heard.REQUEST,
            COB_DETECT_CAPABLE: Heard.DETECT_CAPABLE,
            COB_FORCE_NEGOTIATION: Heard.FORCE,
        }.get(cob_id)

    def _own_id(self, what: str) -> Heard:
        self.duplicates += 1
        if self.conflict is None:
            self.conflict = (
                f"another device uses this gateway's pair id {self.node_id}: heard {what}"
            )
        return Heard.OWN_ID

    def _claim_heard(self, data: bytes, now: float) -> Heard | None:
        if len(data) < 2:
            return None  # malformed
        if data[1] == self.node_id:
            return None if self.echo else self._own_id(f"71h [{data[0]}, {data[1]}]")
        claim = Claim(data[0], data[1], now)
        self.peer = claim
        if self.peer_id is not None and claim.node_id != self.peer_id:
            self.third_party = claim
        if wins((data[0], data[1]), (self.priority, self.node_id)):
            return Heard.OUTBID if self._claim_s is not None else Heard.BETTER_CLAIM
        return Heard.WORSE_CLAIM

    def _fire(self, heard: Heard, now: float) -> list[Action]:
        if self.role is Role.ACTIVE and self.was_cut and heard in _MEETINGS:
            heard = Heard.MET_AFTER_CUT
        if heard in _ALIVE:
            self.active_heard_s = now
        key = (self.role, heard)
        does = DOES.get(key)
        if does is not None:
            actions: list[Action] = getattr(self, does)(now)
            return actions
        nxt = TRANSITIONS.get(key)
        if nxt is None:
            if heard in _TIMERS:
                raise PairError(f"no transition for {heard.value} in {self.role.value}")
            self.ignored += 1
            return []
        return self._enter(nxt, heard, now)

    # what a role does without changing (``DOES``)

    def _alive(self, now: float) -> list[Action]:
        self._deadline_s = now + self.timing.takeover_s
        self._doubt_until_s = None
        return []

    def _wait_for_the_bus(self, now: float) -> list[Action]:
        """The master silent, nothing heard since: a dead master on a quiet bus or a cut
        cable. Wait one more take-over time for any frame (then negotiate), else cut off;
        looking every quarter heartbeat meanwhile (the caller reports at each poll)."""
        if self._doubt_until_s is None:
            self._doubt_until_s = now + self.timing.takeover_s
        self._deadline_s = min(self._doubt_until_s, now + self.timing.heartbeat / 4)
        return []

    def _answer(self, now: float) -> list[Action]:
        return [self.claim_frame()]

    def _capable(self, now: float) -> list[Action]:
        return [Send("send", COB_CAPABLE_RESPONSE, bytes((self.priority, self.node_id)))]

    def _join_slot(self, now: float) -> list[Action]:
        if self._claim_s is None:  # a 72h heard within our slot starts nothing new
            self._claim_s = now + self.timing.slot_s(self.priority, self.node_id)
        return []

    def _negotiate_again(self, now: float) -> list[Action]:
        if self._claim_s is not None:
            return []
        self._join_slot(now)
        return [Send("send", COB_NEGOTIATION_REQUEST, b"")]

    def _force(self, now: float) -> list[Action]:
        """Another master met while active: CiA 302-2's answer, a forced negotiation (76h +
        72h) that the slot decides; at most once per detect cycle, never within its slot."""
        if self._claim_s is not None:
            return []
        if self._forced_s is not None and now - self._forced_s < self.timing.detect_cycle_s:
            self.ignored += 1
            return []
        self._forced_s = now
        self.forced += 1
        self._join_slot(now)
        who = f"priority {self.peer.priority}, node {self.peer.node_id}" if self.peer else "unknown"
        return [
            Notice(
                "notice",
                "forced",
                f"pair: another master is on the bus (last claim: {who}): "
                "negotiation forced (76h, 72h); the time slot decides",
            ),  # fmt: skip
            Send("send", COB_FORCE_NEGOTIATION, b""),
            Send("send", COB_NEGOTIATION_REQUEST, b""),
        ]

    def _claim(self, now: float) -> list[Action]:
        self._claim_s = None
        return [self.claim_frame()]

    def _detect(self, now: float) -> list[Action]:
        self._detect_s = now + self.timing.detect_cycle_s
        return [Send("send", COB_FORCE_NEGOTIATION, b"")]

    def _conflict(self, now: float) -> list[Action]:
        return [Notice("notice", "duplicate", f"pair: {self.conflict}; this gateway keeps the bus")]

    # role changes (``TRANSITIONS``)

    def _enter(self, role: Role, heard: Heard, now: float) -> list[Action]:
        previous, self.role = self.role, role
        self._claim_s = self._detect_s = self._deadline_s = self._doubt_until_s = None
        actions: list[Action] = []
        reason = _REASONS.get(heard, heard.value)
        if role is Role.STANDBY:
            self._deadline_s = now + self.timing.takeover_s
            reason = _standby_reason(heard, self.peer)
        elif role is Role.NEGOTIATING:
            self.negotiations += 1
            self._deadline_s = now + self.timing.slot_s(self.priority, self.node_id)
            if heard is not Heard.NEGOTIATION:
                actions.append(Send("send", COB_NEGOTIATION_REQUEST, b""))
            if heard is Heard.ACTIVE_SILENT:
                reason = f"the active master was silent for {self._ms(self.timing.takeover_s)}"
        elif role is Role.ACTIVE:
            if previous is Role.NEGOTIATING and self.active_heard_s is not None:
                self.takeovers += 1
            self.was_cut = False
            self.heard_s = now  # its deaf window starts at its claim
            self._detect_s = now + self.timing.detect_cycle_s
            actions.append(self.claim_frame())
        elif role is Role.LISTENING:
            self._listened_s = now
            self._deadline_s = now + self.timing.detect_s
            actions.append(Send("send", COB_ACTIVE_MASTER_REQUEST, b""))
        elif role is Role.ISOLATED:
            self.isolations += 1
            if heard is Heard.DEAF:
                reason = f"nothing heard on the bus for {self._ms(self.timing.takeover_s)}: cut off"
        else:  # DUPLICATE
            reason = f"{self.conflict}: this gateway stays out"
        return [RoleChanged("role", role, previous, reason, heard in _OUTAGES), *actions]


_REASONS: dict[Heard, str] = {
    Heard.NEGOTIATION: "another gateway negotiates (72h)",
    Heard.DETECTION_OVER: "no active master heard",
    Heard.SLOT_OVER: "no other claim within the time slot",
    Heard.LINK_LOST: "this gateway's CAN bus is down",
    Heard.BUS_HEARD: "the bus is heard again: listen before joining",
}


def _standby_reason(heard: Heard, peer: Claim | None) -> str:
    if heard is Heard.STALLED:
        return (
            "this gateway did not run for longer than the take-over time: the other may be active"
        )
    if heard is Heard.MET_AFTER_CUT:
        return (
            "another master met after this gateway heard nothing for a while: no fail-back onto it"
        )
    if heard in (Heard.LOGICAL_HEARTBEAT, Heard.FORCE):
        return "the active master is heard"
    who = f"priority {peer.priority}, node {peer.node_id}" if peer else "another gateway"
    if heard in (Heard.BETTER_CLAIM, Heard.OUTBID):
        return f"an active master that wins ({who}) is heard"
    return f"an active master ({who}) is heard: no fail-back"
