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
(``on_frame(cob_id, data, now)``, the peer's own heartbeat ``on_peer_heartbeat``), whether it
hears the bus at all (``on_hearing(now, last_frame_s, nodes_alive)``: when the driver last
received any frame) and whether its bus is open and it can send (``on_link(up, now,
sending)``), calls ``poll(now)`` at ``next_deadline_s()``, and does what the returned actions say
(``Send`` a frame; ``RoleChanged`` tells it to start or stop mastering; ``Notice`` is a line for
the log). Every time is the monotonic bus clock; what was heard when is ``hearing.Hearing``.
Rule 3: decisions from what is heard now. A gateway back from an outage of its own listens as a
fresh joiner (``RoleChanged.fresh``) and as standby whatever its priority; who wins is decided by
(priority, node id), never by which slot ends first.

The frames (CiA 302-2, NMT flying master; the emotas stack's behaviour is the reference): 71h
active master response ``[priority, id]``, sent at a claim (the end of a time slot), per 73h
heard while active, and to a worse master met while active; 72h negotiation request (starts
every capable device's time slot); 73h active master request, sent when a gateway starts
listening; 75h detect master-capable devices, answered by one 74h ``[priority, id]``; 76h force
negotiation, sent by the active one every ``detect_cycle_s`` (1F90h:06). Each member's own
heartbeat (700h + its pair id) says its role in its state byte (``protocol.ROLE_STATE``).

The roles (``*`` any claim, ``<`` a claim that wins against ours by (priority, node id): lower
priority first, then lower node id; ``>`` one that loses; *traffic*: a frame of anyone but this
gateway, after the active master's next heartbeat was due: the last frame's time)::

    role         heard / timer                        next         does
    listening    logical heartbeat, 71h *, 76h        standby      (an active master is there)
    listening    72h                                  negotiating  waits its time slot
    listening    72h, back from an outage             listening    lets them claim: listens
                                                                   its detection time again
                                                                   and the last claim's slot
    listening    detection time over (counted from    negotiating  sends 72h, waits its slot
                 its bus's first frame; a silent bus:
                 ``silent_s``)
    negotiating  logical heartbeat, 71h *             standby      (someone is active)
    negotiating  time slot over                       active       sends 71h
    standby      72h                                  negotiating  waits its time slot
    standby      master silent, traffic heard         negotiating  sends 72h, waits its slot
    standby      the active member's own heartbeat    active       sends 71h (a hand-over: no
                 says it no longer masters                         slot to wait)
    standby      master silent, no traffic in doubt   isolated     sends nothing (cut off)
    standby      master silent, no traffic yet        standby      waits for a frame until the
                                                                   bus must have talked, looks
                                                                   every heartbeat / 4
    active       71h <                                standby      goes silent at once
    active       stalled (no event for takeover_s)    standby      goes silent at once
    active       another master, after a deaf spell   standby      (never a fail-back onto it)
    active       this gateway stops (SIGTERM)         standby      (a planned hand-over)
    active       its 75h drew no 74h                  isolated     its frames do not arrive
    active       no traffic and no node alive         isolated     goes silent at once
    l/n/s/a      bus down, or it cannot send          isolated     goes silent at once
    isolated     traffic heard, bus open, sending     listening    sends 73h (a fresh joiner)
    l/n/s/i      71h or heartbeat of our own pair id  duplicate    sends nothing, ever

    active       73h, 72h, 76h, 71h >, another        active       ``active.ActiveDuties``
                 logical heartbeat, 74h, its timers                (answers, its own timers)
    l/n/s/a      75h                                  (same)       answers 74h

An active gateway's 75h unanswered (``active.py``): its frames do not reach the bus, it stands
down. Two actives resolve within a heartbeat (each answers the other with its claim). An active
one that heard nothing for ``takeover_s`` is *cut* (``was_cut``): meeting another master, it
stands by; ``meetings`` counts every master met while active (its nodes then wait to be heard).

The time slot is CiA 302-2's: ``priority * priority_slot_s + node_id * device_slot_s``
(1F90h:04, 1F90h:05); the defaults here are shorter than 1F90h's (1500 ms, 10 ms) so that a
take-over fits in a second. ``check`` refuses a pair whose slots do not follow the priority
order (a third-party master decides by them).

Imports: bus.pair.protocol (its vocabulary), bus.pair.hearing (what was heard when),
bus.pair.active (what the active role does), bus.pair.reasons (the log's words), bus.transitions (the table's rows), canopen.cia301 (the
heartbeat's COB-ID) and the standard library.
Must not import python-can, asyncio, logging, config or any northbound module.
"""

from __future__ import annotations

from canopen_gateway.bus.pair.active import ActiveDuties
from canopen_gateway.bus.pair.hearing import Hearing
from canopen_gateway.bus.pair.protocol import (
    COB_ACTIVE_MASTER_REQUEST,
    COB_ACTIVE_MASTER_RESPONSE,
    COB_CAPABLE_RESPONSE,
    COB_DETECT_CAPABLE,
    COB_FORCE_NEGOTIATION,
    COB_NEGOTIATION_REQUEST,
    FLYING_MASTER_COB_IDS,
    NOT_ACTIVE_STATE,
    PEER_ROLE,
    ROLE_STATE,
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
from canopen_gateway.bus.pair.reasons import reason
from canopen_gateway.bus.transitions import transition_table
from canopen_gateway.canopen.cia301 import COB_NMT_EC as COB_HEARTBEAT  # heartbeat, + node id

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
    ((_S,), (_H.STEPPED_DOWN,), _A),
    ((_A,), (_H.BETTER_CLAIM, _H.OUTBID, _H.STALLED, _H.MET_AFTER_CUT, _H.LEAVING), _S),
    ((_S, _A), (_H.DEAF,), _I),
    ((_A,), (_H.UNANSWERED,), _I),
    ((_L, _N, _S, _A), (_H.LINK_LOST, _H.CANNOT_SEND), _I),
    ((_I,), (_H.BUS_HEARD,), _L),
    ((_L, _N, _S, _I), (_H.OWN_ID,), _D),
)
#: (role, heard) -> what the role does without changing (a method of ``FlyingMaster``)
DOES: dict[tuple[Role, Heard], str] = {
    **{
        (_S, h): "_alive" for h in (_H.LOGICAL_HEARTBEAT, _H.BETTER_CLAIM, _H.WORSE_CLAIM, _H.FORCE)
    },
    (_S, _H.UNHEARD): "_wait_for_the_bus",
    (_L, _H.NEGOTIATION_WHILE_BACK): "_let_them_claim",
    (_A, _H.REQUEST): "duties.answer",
    (_A, _H.NEGOTIATION): "duties.join_slot",
    (_A, _H.FORCE): "duties.negotiate_again",
    (_A, _H.WORSE_CLAIM): "duties.outclaim",
    (_A, _H.FOREIGN_LOGICAL): "duties.outclaim",
    (_A, _H.CAPABLE): "duties.answered",
    (_A, _H.CLAIM_DUE): "duties.claim",
    (_A, _H.DETECT_DUE): "duties.detect",
    (_A, _H.OWN_ID): "_conflict",
    **{(r, _H.DETECT_CAPABLE): "_capable" for r in (_L, _N, _S, _A)},
}
#: heard while active after a deaf spell: another master is there, this one stands by
_MEETINGS = frozenset(
    {_H.BETTER_CLAIM, _H.WORSE_CLAIM, _H.FORCE, _H.NEGOTIATION, _H.FOREIGN_LOGICAL}
)
#: heard while active: another master-capable device is there; its 75h makes sure our frames
#: arrive (not for the logical heartbeat alone: a device stuck on its COB-ID answers no 75h)
_OTHERS = frozenset({_H.WORSE_CLAIM, _H.FORCE, _H.NEGOTIATION})
#: what tells the standby the active master is alive
_ALIVE = frozenset({_H.LOGICAL_HEARTBEAT, _H.BETTER_CLAIM, _H.WORSE_CLAIM, _H.FORCE})
#: what says this gateway was out (its own outage): it comes back as a fresh joiner
_OUTAGES = frozenset(
    {_H.LINK_LOST, _H.CANNOT_SEND, _H.DEAF, _H.UNANSWERED, _H.BUS_HEARD, _H.STALLED,
     _H.MET_AFTER_CUT, _H.OWN_ID}
)  # fmt: skip
_TIMERS = frozenset(
    {_H.DETECTION_OVER, _H.SLOT_OVER, _H.ACTIVE_SILENT, _H.DEAF, _H.CLAIM_DUE, _H.DETECT_DUE,
     _H.UNHEARD, _H.UNANSWERED}
)  # fmt: skip


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
        #: the other member's own heartbeat: (its state byte, when), if heard
        self.peer_state: tuple[int, float] | None = None
        self.hearing = Hearing(timing)
        self.link_up = True
        self.sending = True  # its driver says its frames can go out (not bus off, queue free)
        self.back = False  # listening back from an outage of its own (not at its start)
        #: heard nothing for takeover_s while active: it may have missed a take-over
        self.was_cut = False
        #: what a device with our own pair id was heard sending (None: nothing)
        self.conflict: str | None = None
        self.ignored = 0  # frames that meant nothing in the role (our own echo among them)
        self.takeovers = 0  # standby -> active through a negotiation or a hand-over
        self.negotiations = 0
        self.stalls = 0  # active -> standby because this gateway stalled
        self.isolations = 0  # -> isolated (bus down, cannot send, or nothing heard)
        self.duplicates = 0  # frames of another device with our own pair id
        self.meetings = 0  # another master met while active
        #: the active role's answers and timers
        self.duties = ActiveDuties(priority, node_id, timing, self._who)
        self._deadline_s: float | None = None  # the role's timer (not the active one's)
        #: standby: the master silent, the bus not heard since: until when it waits for a frame
        self._doubt_until_s: float | None = None

    # ------------------------------------------------------------------ queries
    @property
    def active(self) -> bool:
        return self.role is Role.ACTIVE

    @property
    def heard_s(self) -> float | None:
        return self.hearing.heard_s

    @property
    def active_heard_s(self) -> float | None:
        return self.hearing.active_heard_s

    @property
    def master_heard(self) -> bool:
        """An active master was heard since this gateway last began listening (its start, or
        back from an outage): a take-over replaces it (not a first start of the bus)."""
        return self.hearing.master_heard

    @property
    def own_state(self) -> int:
        """The state byte of this member's own heartbeat: its role (``ROLE_STATE``)."""
        return ROLE_STATE.get(self.role, NOT_ACTIVE_STATE)

    def peer_role(self, now: float) -> str:
        """The other member's role as heard within the take-over time: ``active``,
        ``standby``, ``isolated`` (its own heartbeat says so) or ``unknown``."""
        state = self.peer_state
        if state is None or now - state[1] > self.timing.takeover_s:
            return "unknown"
        return PEER_ROLE.get(state[0] & 0x7F, "unknown")

    def next_deadline_s(self) -> float | None:
        """When ``poll`` must run next (``None``: no timer in this role)."""
        if not self.started:
            return None
        if self.role is Role.ACTIVE:
            return self.duties.next_deadline_s()
        return self._deadline_s

    def _who(self) -> str:
        return f"priority {self.peer.priority}, node {self.peer.node_id}" if self.peer else "unknown"

    # ------------------------------------------------------------------ events
    def start(self, now: float) -> list[Action]:
        """Start listening: one active master request (73h), then wait for the bus."""
        if self.started:
            raise PairError("the pair machine is started once")
        self.started = True
        self.hearing.listen(now, delivered=False)
        self._deadline_s = self.hearing.detection_due_s(now)
        return [Send("send", COB_ACTIVE_MASTER_REQUEST, b"")]

    def on_frame(self, cob_id: int, data: bytes, now: float) -> list[Action]:
        """A frame heard on the bus (the flying-master ids, the logical heartbeat, the
        heartbeats of our own pair id and of a third-party master; others are not passed)."""
        heard = self._classify(cob_id, data, now)
        if heard is None:
            self.ignored += 1
            return []
        self.hearing.heard(now)
        actions: list[Action] = []
        if self.role is Role.ISOLATED and self.link_up and self.sending:
            actions = self._fire(Heard.BUS_HEARD, now)
        return actions + self._fire(heard, now)

    def on_peer_heartbeat(self, data: bytes, now: float) -> list[Action]:
        """The other member's own heartbeat (its role in its state byte). A standby whose
        active member says it no longer masters the bus (it stops, it stood down) takes over
        at once."""
        if not data:
            return []
        self.hearing.heard(now)
        self.peer_state = (data[0], now)
        if self.role is Role.ISOLATED and self.link_up and self.sending:
            return self._fire(Heard.BUS_HEARD, now)
        claim = self.peer
        if (
            self.role is Role.STANDBY
            and data[0] & 0x7F != ROLE_STATE[Role.ACTIVE]
            and claim is not None
            and claim.node_id == self.peer_id
            and self.hearing.active_heard_s is not None
            and now - self.hearing.active_heard_s <= self.timing.takeover_s
        ):
            return self._fire(Heard.STEPPED_DOWN, now)
        return []

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
        if last_frame_s is not None and self.hearing.heard(min(last_frame_s, now)):
            if self.role is Role.ISOLATED and self.link_up and self.sending:
                return self._fire(Heard.BUS_HEARD, now)
            if (
                self.role is Role.STANDBY
                and self._doubt_until_s is not None
                and self.hearing.master_gone()
            ):
                return self._fire(Heard.ACTIVE_SILENT, now)
            return []
        if self.role is not Role.ACTIVE or self.hearing.within(now, self.timing.takeover_s):
            return []
        out: list[Action] = []
        if not self.was_cut:
            self.was_cut = True
            text = f"pair: active, and nothing heard for {self._ms(self.timing.takeover_s)}"
            out.append(Notice("notice", "deaf", text))
        if not nodes_alive:
            out += self._fire(Heard.DEAF, now)
        return out

    def on_link(self, up: bool, now: float, sending: bool = True) -> list[Action]:
        """The bus went down (open failed, connection lost) or is open again; ``sending``
        False: open, but its frames cannot go out (bus off, error passive, sends refused)."""
        was = self.link_up and self.sending
        self.link_up, self.sending = up, sending
        if (up and sending) or not was or not self.started:
            return []
        if self.role in (Role.ISOLATED, Role.DUPLICATE):
            return []
        return self._fire(Heard.LINK_LOST if not up else Heard.CANNOT_SEND, now)

    def on_stall(self, now: float) -> list[Action]:
        """The caller found that this gateway did not run for longer than the take-over time
        (its process frozen, its machine starved): an active one stands by at once."""
        if self.role is not Role.ACTIVE:
            return []
        self.stalls += 1
        return self._fire(Heard.STALLED, now)

    def hand_over(self, now: float) -> list[Action]:
        """This gateway stops (SIGTERM): an active one stands by; its own heartbeat then says
        so and the standby takes the bus at once (``on_peer_heartbeat``)."""
        if self.role is not Role.ACTIVE:
            return []
        return self._fire(Heard.LEAVING, now)

    def poll(self, now: float) -> list[Action]:
        """The deadline of the role has come (or not yet: then nothing happens)."""
        if not self.started:
            return []
        if self.role is Role.ACTIVE:
            due = self.duties.due(now)
            return self._fire(due, now) if due is not None else []
        if self._deadline_s is None or now < self._deadline_s:
            return []
        if self.role is Role.STANDBY:
            heard = Heard.ACTIVE_SILENT if self.hearing.master_gone() else Heard.UNHEARD
            if heard is Heard.UNHEARD and self._doubt_until_s is not None:
                heard = Heard.DEAF if now >= self._doubt_until_s else Heard.UNHEARD
        elif self.role is Role.LISTENING:
            if self.hearing.detection_over(now) is None:
                self._deadline_s = self.hearing.detection_due_s(now)  # looks again
                return []
            heard = Heard.DETECTION_OVER
        else:
            heard = Heard.SLOT_OVER  # negotiating (isolated, duplicate: no timer)
        return self._fire(heard, now)

    @staticmethod
    def _ms(seconds: float) -> str:
        return f"{seconds * 1000:.0f} ms"

    # ------------------------------------------------------------------ what a frame is
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
        if cob_id == COB_CAPABLE_RESPONSE:
            return Heard.CAPABLE if len(data) >= 2 and data[1] != self.node_id else None
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
            return Heard.OUTBID if self.duties.claim_s is not None else Heard.BETTER_CLAIM
        return Heard.WORSE_CLAIM

    def _fire(self, heard: Heard, now: float) -> list[Action]:
        if self.role is Role.ACTIVE and heard in _MEETINGS:
            self.meetings += 1  # another master met while active (``RoleChanged`` aside)
            heard = Heard.MET_AFTER_CUT if self.was_cut else heard
        elif self.role is Role.LISTENING and self.back and heard is Heard.NEGOTIATION:
            heard = Heard.NEGOTIATION_WHILE_BACK  # no fail-back onto a member that was out
        if heard in _ALIVE:
            self.hearing.master(now)
        key = (self.role, heard)
        does = DOES.get(key)
        if does is not None:
            on, name = (self.duties, does[7:]) if does.startswith("duties.") else (self, does)
            actions: list[Action] = getattr(on, name)(now)
            if self.role is Role.ACTIVE and heard in _OTHERS:
                actions += self.duties.probe(now)
            return actions
        nxt = TRANSITIONS.get(key)
        if nxt is None:
            if heard in _TIMERS:
                raise PairError(f"no transition for {heard.value} in {self.role.value}")
            self.ignored += 1
            return []
        return self._enter(nxt, heard, now)

    # ------------------------------------------------------------------ what a role does (``DOES``)
    def _alive(self, now: float) -> list[Action]:
        self._deadline_s = now + self.timing.takeover_s
        self._doubt_until_s = None
        return []

    def _let_them_claim(self, now: float) -> list[Action]:
        """Back from an outage, it hears another gateway negotiate: that one has been on the
        bus and knows it; it claims first (the detection time runs again, and the slot of the
        last claim heard), and this one joins it as standby."""
        last = self.peer
        slot = self.timing.slot_s(last.priority, last.node_id) if last is not None else 0.0
        self.hearing.first_s = now
        self._deadline_s = now + self.timing.detect_s + slot
        return []

    def _wait_for_the_bus(self, now: float) -> list[Action]:
        """The master silent, nothing heard since: a dead master on a quiet bus or a cut
        cable. Wait for any frame until the devices must have talked (then negotiate), else cut
        off; looking every quarter heartbeat meanwhile (the caller reports at each poll)."""
        if self._doubt_until_s is None:
            self._doubt_until_s = self.hearing.doubt_until_s(now)
        self._deadline_s = min(self._doubt_until_s, now + self.timing.heartbeat / 4)
        return []

    def _capable(self, now: float) -> list[Action]:
        return [Send("send", COB_CAPABLE_RESPONSE, bytes((self.priority, self.node_id)))]

    def _conflict(self, now: float) -> list[Action]:
        return [Notice("notice", "duplicate", f"pair: {self.conflict}; this gateway keeps the bus")]

    # ------------------------------------------------------------------ role changes (``TRANSITIONS``)
    def _enter(self, role: Role, heard: Heard, now: float) -> list[Action]:
        previous, self.role = self.role, role
        self._deadline_s = self._doubt_until_s = None
        self.duties.end()
        actions: list[Action] = []
        why = reason(heard, self.timing, self.peer, self.conflict)
        if role is Role.STANDBY:
            self._deadline_s = now + self.timing.takeover_s
        elif role is Role.NEGOTIATING:
            self.negotiations += 1
            self._deadline_s = now + self.timing.slot_s(self.priority, self.node_id)
            if heard is not Heard.NEGOTIATION:
                actions.append(Send("send", COB_NEGOTIATION_REQUEST, b""))
        elif role is Role.ACTIVE:
            if previous is Role.STANDBY or (
                previous is Role.NEGOTIATING and self.hearing.active_heard_s is not None
            ):
                self.takeovers += 1  # through a negotiation, or a hand-over
            self.was_cut = False
            self.hearing.heard(now)  # its deaf window starts at its claim
            self.duties.begin(now)
            actions.append(self.duties.claim_frame())
        elif role is Role.LISTENING:
            self.back = heard is Heard.BUS_HEARD
            self.hearing.listen(now, delivered=self.back)
            self._deadline_s = self.hearing.detection_due_s(now)
            actions.append(Send("send", COB_ACTIVE_MASTER_REQUEST, b""))
        elif role is Role.ISOLATED:
            self.isolations += 1
        return [RoleChanged("role", role, previous, why, heard in _OUTAGES), *actions]
