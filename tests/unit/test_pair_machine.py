"""The role machine of a hot-standby pair (CiA 302-2 flying master), on a fake bus and clock.

A ``Pair`` joins machines by a fake bus: a frame one sends reaches every other machine that is
up and not cut at the same instant; an active machine's gateway produces the logical heartbeat
every period, every gateway its own heartbeat, and ``devices`` a device heartbeat (0x701) every
200 ms. Every period each gateway reports whether it received anything (``on_hearing``: the
time of the last frame the driver received). Gateways can be killed (silent, gone), frozen (silent, then
back with their state), restarted, cut (they hear nothing and nothing they send arrives) and
lose their adapter (``on_link(False)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from canopen_gateway.bus.pair.flying_master import (
    COB_ACTIVE_MASTER_REQUEST,
    COB_ACTIVE_MASTER_RESPONSE,
    COB_CAPABLE_RESPONSE,
    COB_DETECT_CAPABLE,
    COB_FORCE_NEGOTIATION,
    COB_HEARTBEAT,
    COB_NEGOTIATION_REQUEST,
    DOES,
    FLYING_MASTER_COB_IDS,
    TRANSITIONS,
    FlyingMaster,
    Notice,
    PairError,
    PairTiming,
    Role,
    RoleChanged,
    Send,
)

MASTER = 100
HEARTBEAT_S = 0.1
DEVICE_PERIOD_S = 0.2
TIMING = PairTiming(takeover_s=3 * HEARTBEAT_S, detect_s=3 * HEARTBEAT_S)


def machine(
    node_id: int, priority: int, timing: PairTiming = TIMING, **kw: object
) -> FlyingMaster:
    return FlyingMaster(
        node_id=node_id, priority=priority, master_node_id=MASTER, timing=timing, **kw
    )  # type: ignore[arg-type]


@dataclass
class Gateway:
    name: str
    fm: FlyingMaster
    up: bool = True
    cut: bool = False
    next_heartbeat_s: float = math.inf
    next_own_s: float = 0.0
    last_rx_s: float | None = None  # when it last received a frame (the driver's reader)
    roles: list[tuple[float, Role, str]] = field(default_factory=list)
    notices: list[str] = field(default_factory=list)
    nodes_alive: bool = False


class ThirdParty:
    """A CiA 302-2 flying master of another vendor, written from the behaviour the emotas stack
    ships (not from our machine): 73h answered by the active one with 71h; a worse 71h heard
    while active: 76h + 72h and its slot; 72h: its slot; 76h while active: 72h and its slot; at
    its slot's end 71h unless a better 71h came first; active: 76h every 4 s and its heartbeat."""

    def __init__(self, node_id: int, priority: int):
        self.name, self.node_id, self.priority = "T", node_id, priority
        self.active = False
        self.slot_end: float | None = None
        self.next_detect = math.inf
        self.next_hb = math.inf
        self.up = True

    def slot(self, now: float) -> None:
        if self.slot_end is None:
            self.slot_end = now + self.priority * 0.2 + self.node_id * 0.002

    def on_frame(self, cob: int, data: bytes, now: float) -> list[tuple[int, bytes]]:
        me = bytes((self.priority, self.node_id))
        if cob == COB_ACTIVE_MASTER_REQUEST and self.active:
            return [(COB_ACTIVE_MASTER_RESPONSE, me)]
        if cob == COB_ACTIVE_MASTER_RESPONSE and len(data) == 2:
            if (data[0], data[1]) < (self.priority, self.node_id):
                self.active, self.slot_end, self.next_hb = False, None, math.inf
                return []
            if self.active and self.slot_end is None:
                self.slot(now)
                return [(COB_FORCE_NEGOTIATION, b""), (COB_NEGOTIATION_REQUEST, b"")]
        if cob == COB_NEGOTIATION_REQUEST:
            self.slot(now)
        if cob == COB_FORCE_NEGOTIATION and self.active and self.slot_end is None:
            self.slot(now)
            return [(COB_NEGOTIATION_REQUEST, b"")]
        return []

    def deadline(self) -> float:
        return min(self.slot_end or math.inf, self.next_detect, self.next_hb)

    def poll(self, now: float) -> list[tuple[int, bytes]]:
        if self.slot_end is not None and now >= self.slot_end:
            self.slot_end = None
            self.active = True
            self.next_detect, self.next_hb = now + 4.0, now
            return [(COB_ACTIVE_MASTER_RESPONSE, bytes((self.priority, self.node_id)))]
        if now >= self.next_hb:
            self.next_hb = now + HEARTBEAT_S
            return [(COB_HEARTBEAT + self.node_id, b"\x05")]
        if now >= self.next_detect:
            self.next_detect = now + 4.0
            return [(COB_FORCE_NEGOTIATION, b"")]
        return []


@dataclass
class Pair:
    """Discrete-event run of several machines on one fake bus."""

    gateways: dict[str, Gateway] = field(default_factory=dict)
    now: float = 0.0
    log: list[tuple[float, str, int, bytes]] = field(default_factory=list)  # (t, sender, cob, data)
    devices: bool = True
    next_device_s: float = 0.0
    third: ThirdParty | None = None

    def add(self, name: str, node_id: int, priority: int, **kw: object) -> Gateway:
        gw = Gateway(name, machine(node_id, priority, **kw))
        gw.next_own_s = self.now
        self.gateways[name] = gw
        self._act(gw, gw.fm.start(self.now))
        return gw

    def restart(self, name: str) -> Gateway:
        old = self.gateways[name].fm
        return self.add(name, old.node_id, old.priority, peer_id=old.peer_id)

    def add_third_party(self, node_id: int, priority: int) -> ThirdParty:
        self.third = ThirdParty(node_id, priority)
        self.third.slot_end = self.now + 0.1 + priority * 0.2 + node_id * 0.002  # no answer: claim
        self._send_third(COB_ACTIVE_MASTER_REQUEST, b"")
        return self.third

    def _send_third(self, cob_id: int, data: bytes) -> None:
        self.log.append((self.now, "T", cob_id, data))
        for gw in self.gateways.values():
            if gw.up and not gw.cut:
                gw.last_rx_s = self.now
                self._act(gw, gw.fm.on_frame(cob_id, data, self.now))

    def _send(self, sender: Gateway, cob_id: int, data: bytes) -> None:
        self.log.append((self.now, sender.name, cob_id, data))
        if sender.cut:
            return  # nothing it sends arrives
        for gw in self.gateways.values():
            if gw is not sender and gw.up and not gw.cut:
                gw.last_rx_s = self.now
                self._act(gw, gw.fm.on_frame(cob_id, data, self.now))
        t = self.third
        if t is not None and t.up:
            for c, d in t.on_frame(cob_id, data, self.now):
                self._send_third(c, d)

    def _act(self, gw: Gateway, actions: list) -> None:
        for a in actions:
            if isinstance(a, Send):
                self._send(gw, a.cob_id, a.data)
            elif isinstance(a, Notice):
                gw.notices.append(a.text)
            elif isinstance(a, RoleChanged):
                gw.roles.append((self.now, a.role, a.reason))
                if a.role is Role.ACTIVE:
                    gw.next_heartbeat_s = self.now  # the logical heartbeat starts at once
                else:
                    gw.next_heartbeat_s = math.inf

    def _events(self) -> list[tuple[float, int, str]]:
        events: list[tuple[float, int, str]] = []
        for gw in self.gateways.values():
            if not gw.up:
                continue
            d = gw.fm.next_deadline_s()
            if d is not None:
                events.append((d, 0, gw.name))
            events.append((gw.next_heartbeat_s, 1, gw.name))
            events.append((gw.next_own_s, 2, gw.name))
        if self.devices:
            events.append((self.next_device_s, 3, ""))
        if self.third is not None and self.third.up:
            events.append((self.third.deadline(), 4, "T"))
        return events

    def run_until(self, t_end: float) -> None:
        while True:
            events = self._events()
            t, kind, name = min(events) if events else (math.inf, 0, "")
            if t > t_end:
                self.now = t_end
                return
            self.now = max(self.now, t)
            if kind == 3:
                self.next_device_s = self.now + DEVICE_PERIOD_S
                for gw in self.gateways.values():
                    gw.last_rx_s = gw.last_rx_s if gw.cut else self.now
                continue
            if kind == 4:
                assert self.third is not None
                for c, d in self.third.poll(self.now):
                    self._send_third(c, d)
                continue
            gw = self.gateways[name]
            if kind == 0:
                self._act(gw, gw.fm.poll(self.now))
            elif kind == 1:
                gw.next_heartbeat_s = self.now + HEARTBEAT_S
                self._send(gw, COB_HEARTBEAT + MASTER, b"\x05")
            else:  # its own heartbeat, and its report of what it heard
                gw.next_own_s = self.now + HEARTBEAT_S
                self._act(gw, gw.fm.on_hearing(self.now, gw.last_rx_s, gw.nodes_alive))
                if gw.fm.role is not Role.DUPLICATE:
                    self._send(gw, COB_HEARTBEAT + gw.fm.node_id, b"\x05")

    def heartbeat_senders(self, since: float) -> set[str]:
        return {s for t, s, c, _ in self.log if c == COB_HEARTBEAT + MASTER and t >= since}

    def last_heartbeat(self, sender: str) -> float:
        return max(t for t, s, c, _ in self.log if c == COB_HEARTBEAT + MASTER and s == sender)

    def first_heartbeat(self, sender: str, since: float) -> float:
        return min(
            t
            for t, s, c, _ in self.log
            if c == COB_HEARTBEAT + MASTER and s == sender and t >= since
        )

    def sent(self, sender: str, cob_id: int, since: float = 0.0) -> int:
        return sum(1 for t, s, c, _ in self.log if s == sender and c == cob_id and t >= since)

    def pair_frames(self, since: float, sender: str | None = None) -> int:
        return sum(
            1
            for t, s, c, _ in self.log
            if c in FLYING_MASTER_COB_IDS and t >= since and sender in (None, s)
        )


def a_active_b_standby() -> tuple[Pair, Gateway, Gateway]:
    """A (priority 0) started alone and active, B (priority 1) joined a second later, at 5 s."""
    pair = Pair()
    a = pair.add("A", node_id=101, priority=0)
    pair.run_until(1.0)
    b = pair.add("B", node_id=102, priority=1)
    pair.run_until(5.0)
    return pair, a, b


# ------------------------------------------------------------------ start


def test_a_gateway_alone_negotiates_and_claims_after_the_detection_time() -> None:
    pair = Pair()
    a = pair.add("A", node_id=101, priority=0)
    assert pair.log[0][2] == COB_ACTIVE_MASTER_REQUEST  # 73h first: who is active?
    pair.run_until(1.0)
    assert a.fm.role is Role.ACTIVE
    slot = TIMING.slot_s(0, 101)
    claim_at = next(t for t, s, c, _ in pair.log if c == COB_ACTIVE_MASTER_RESPONSE)
    assert claim_at == pytest.approx(TIMING.detect_s + slot)
    assert pair.sent("A", COB_NEGOTIATION_REQUEST) == 1
    assert [r for _, r, _ in a.roles] == [Role.NEGOTIATING, Role.ACTIVE]


def test_a_second_gateway_that_hears_the_active_one_stays_standby_and_sends_one_request() -> None:
    pair = Pair()
    pair.add("A", node_id=101, priority=0)
    pair.run_until(1.0)
    b = pair.add("B", node_id=102, priority=1)
    pair.run_until(30.0)
    assert b.fm.role is Role.STANDBY
    assert pair.sent("B", COB_ACTIVE_MASTER_REQUEST) == 1
    assert {c for _, s, c, _ in pair.log if s == "B"} == {COB_ACTIVE_MASTER_REQUEST, 0x700 + 102}
    assert pair.heartbeat_senders(since=1.0) == {"A"}
    assert b.fm.peer is not None and b.fm.peer.node_id == 101


def test_both_starting_together_end_with_one_active_the_winner_by_priority() -> None:
    pair = Pair()
    a = pair.add("A", node_id=101, priority=1)
    b = pair.add("B", node_id=102, priority=0)
    pair.run_until(5.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.ACTIVE)
    assert pair.heartbeat_senders(since=1.0) == {"B"}


def test_equal_priority_the_lower_node_id_wins() -> None:
    pair = Pair()
    a = pair.add("A", node_id=110, priority=0)
    b = pair.add("B", node_id=105, priority=0)
    pair.run_until(5.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.ACTIVE)


# ------------------------------------------------------------------ take-over


def test_when_the_active_one_dies_the_standby_takes_over_within_a_second() -> None:
    pair, a, b = a_active_b_standby()
    a.up = False  # SIGKILL
    last_a = pair.last_heartbeat("A")
    pair.run_until(10.0)
    assert b.fm.role is Role.ACTIVE and b.fm.takeovers == 1
    gap = pair.first_heartbeat("B", since=last_a) - last_a
    assert gap <= 1.0
    # counted from A's last logical heartbeat (the standby's deadline), within one period
    silent_s = TIMING.takeover_s + TIMING.slot_s(1, 102)
    assert silent_s - 1e-9 <= gap <= silent_s + HEARTBEAT_S
    assert "silent" in b.roles[-2][2]


def test_a_restarted_gateway_joins_as_standby_even_with_the_better_priority() -> None:
    pair, a, b = a_active_b_standby()
    a.up = False
    pair.run_until(10.0)
    a = pair.restart("A")
    pair.run_until(20.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.ACTIVE)
    assert pair.heartbeat_senders(since=10.0) == {"B"}
    assert "no fail-back" in a.roles[-1][2]


def test_a_frozen_active_one_is_replaced_and_when_thawed_one_sender_remains_at_once() -> None:
    pair, a, b = a_active_b_standby()
    a.up = False
    pair.run_until(10.0)  # B active
    b.up = False  # SIGSTOP for 2 s: B keeps its state
    frozen_at = pair.now
    a = pair.restart("A")  # A comes back while B is frozen: nobody answers
    pair.run_until(frozen_at + 4.0)
    assert a.fm.role is Role.ACTIVE
    b.up = True  # SIGCONT: B still believes it is active, until it sees it did not run
    thawed_at = pair.now
    pair._act(b, b.fm.on_stall(pair.now))  # what PairMember.check does at its first event
    assert b.fm.role is Role.STANDBY and b.fm.stalls == 1
    pair.run_until(thawed_at + 0.5)
    assert (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY)
    last_b = pair.last_heartbeat("B")
    assert last_b - thawed_at <= 0.5
    pair.run_until(thawed_at + 5.0)
    assert pair.heartbeat_senders(since=thawed_at + 0.5) == {"A"}


def test_two_actives_that_hear_each_other_resolve_by_priority_within_a_heartbeat() -> None:
    pair = Pair()
    a = pair.add("A", node_id=101, priority=0)
    pair.run_until(1.0)
    b = pair.add("B", node_id=102, priority=1)
    pair.run_until(2.0)
    # a partition ends: both believed themselves active (neither heard nothing meanwhile)
    b.fm.role = Role.ACTIVE
    b.next_heartbeat_s = pair.now
    pair.run_until(2.0 + HEARTBEAT_S + 0.01)
    assert (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY)
    # A heard another sender of the logical heartbeat and answered with its claim: B, worse,
    # stood by on it (no slot to wait); A made sure its frames arrive (75h, B's 74h)
    assert a.fm.duties.outclaims == 1 and pair.sent("A", COB_ACTIVE_MASTER_RESPONSE, since=2.0) == 1
    pair.run_until(5.0)
    assert pair.heartbeat_senders(since=2.2) == {"A"} and a.fm.role is Role.ACTIVE
    assert pair.pair_frames(since=2.0) <= 5
    assert any("answered with our claim" in n for n in a.notices)


def test_a_standby_that_keeps_hearing_the_logical_heartbeat_never_negotiates() -> None:
    fm = machine(102, 1)
    fm.start(0.0)
    fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 0.05)
    assert fm.role is Role.STANDBY
    t = 0.05
    for _ in range(36_000):  # an hour of 100 ms heartbeats
        t += HEARTBEAT_S
        assert fm.poll(t) == []
        fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", t)
    assert fm.role is Role.STANDBY and fm.negotiations == 0


def test_the_takeover_edge_is_exactly_the_takeover_time() -> None:
    fm = machine(102, 1)
    fm.start(0.0)
    fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 1.0)
    assert fm.poll(math.nextafter(1.0 + TIMING.takeover_s, 0)) == []
    fm.on_hearing(1.25, last_frame_s=1.25)  # a device heard after the next heartbeat was due
    actions = fm.poll(1.0 + TIMING.takeover_s)
    assert fm.role is Role.NEGOTIATING
    assert Send("send", COB_NEGOTIATION_REQUEST, b"") in actions


# ------------------------------------------------------------------ answers and edges


def active_machine(node_id: int = 101, priority: int = 0, **kw: object) -> FlyingMaster:
    fm = machine(node_id, priority, **kw)
    fm.start(0.0)
    fm.on_hearing(0.05, last_frame_s=0.05)  # its bus delivers: the detection time runs
    fm.poll(1.0)
    fm.poll(2.0)
    assert fm.role is Role.ACTIVE
    return fm


CLAIM = Send("send", COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101)))
PROBE = Send("send", COB_DETECT_CAPABLE, b"")


def test_the_active_one_answers_73h_with_one_claim() -> None:
    fm = active_machine()
    assert fm.on_frame(COB_ACTIVE_MASTER_REQUEST, b"", 2.5) == [CLAIM]
    assert fm.role is Role.ACTIVE


def test_the_active_one_answers_72h_with_one_claim_at_the_end_of_its_slot_and_stays() -> None:
    fm = active_machine()
    # a master-capable device negotiates: the active one makes sure its frames arrive (75h)
    assert fm.on_frame(COB_NEGOTIATION_REQUEST, b"", 2.5) == [PROBE]
    assert fm.on_frame(COB_CAPABLE_RESPONSE, bytes((1, 102)), 2.51) == []  # they do
    assert fm.on_frame(COB_NEGOTIATION_REQUEST, b"", 2.6) == []  # within the slot: nothing new
    slot_end = 2.5 + TIMING.slot_s(0, 101)
    assert fm.next_deadline_s() == pytest.approx(slot_end)
    assert fm.poll(slot_end) == [CLAIM]
    assert fm.role is Role.ACTIVE and fm.next_deadline_s() == pytest.approx(2.0 + 4.0)


def test_76h_makes_the_active_one_negotiate_again_with_one_72h_then_its_claim() -> None:
    fm = active_machine()
    assert fm.on_frame(COB_FORCE_NEGOTIATION, b"", 2.5) == [
        Send("send", COB_NEGOTIATION_REQUEST, b""), PROBE
    ]
    fm.on_frame(COB_CAPABLE_RESPONSE, bytes((1, 102)), 2.51)
    assert fm.on_frame(COB_FORCE_NEGOTIATION, b"", 2.55) == []
    assert fm.poll(2.5 + TIMING.slot_s(0, 101)) == [CLAIM]


def test_an_active_one_whose_75h_draws_no_74h_stands_down_its_frames_do_not_arrive() -> None:
    """A mute transmitter (frames dropped, the driver unaware): another member negotiates,
    the active one's 75h draws no answer within two heartbeats: it stands down, a fresh joiner."""
    fm = active_machine()
    assert fm.on_frame(COB_NEGOTIATION_REQUEST, b"", 2.5) == [PROBE]
    assert fm.poll(math.nextafter(2.5 + TIMING.answer_s, 0)) == []
    (change,) = fm.poll(2.5 + TIMING.answer_s)
    assert isinstance(change, RoleChanged) and change.role is Role.ISOLATED and change.fresh
    assert "drew no answer" in change.reason and fm.next_deadline_s() is None


def test_the_active_one_sends_76h_every_detect_cycle_and_no_periodic_claim() -> None:
    fm = active_machine()
    sent = [a for t in range(21, 200) for a in fm.poll(t / 10)]  # 2.1 .. 19.9 s
    assert sent == [Send("send", COB_FORCE_NEGOTIATION, b"")] * 4  # at 6, 10, 14, 18 s


def test_75h_is_answered_with_74h_by_every_capable_member_but_one_cut_off() -> None:
    fm = machine(102, 1)
    fm.start(0.0)
    answer = Send("send", COB_CAPABLE_RESPONSE, bytes((1, 102)))
    assert fm.on_frame(COB_DETECT_CAPABLE, b"", 0.1) == [answer]
    fm.on_link(False, 0.2)
    assert fm.role is Role.ISOLATED
    assert fm.on_frame(COB_DETECT_CAPABLE, b"", 0.3) == []  # link down: it hears nothing


def test_our_own_claim_and_heartbeat_echoed_by_the_bus_change_nothing() -> None:
    fm = active_machine(echo=True)
    assert fm.on_frame(COB_HEARTBEAT + 101, b"\x05", 21.0) == []
    assert fm.ignored == 1
    fm.ignored = 0
    assert fm.on_frame(COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101)), 21.0) == []
    assert fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 21.0) == []
    assert fm.role is Role.ACTIVE and fm.ignored == 2


def test_a_short_claim_is_ignored() -> None:
    fm = machine(101, 0)
    fm.start(0.0)
    assert fm.on_frame(COB_ACTIVE_MASTER_RESPONSE, b"\x00", 0.1) == []
    assert fm.role is Role.LISTENING


def test_a_standby_joins_a_negotiation_another_starts_without_sending_72h() -> None:
    fm = machine(102, 1)
    fm.start(0.0)
    fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 0.1)
    actions = fm.on_frame(COB_NEGOTIATION_REQUEST, b"", 0.2)
    assert fm.role is Role.NEGOTIATING
    assert not [a for a in actions if isinstance(a, Send)]


def test_every_transition_of_the_table_is_reachable_and_the_timers_have_one() -> None:
    roles = {r for r, _ in TRANSITIONS} | set(TRANSITIONS.values())
    assert roles == set(Role)


def test_started_twice_is_our_own_misuse() -> None:
    fm = machine(101, 0)
    fm.start(0.0)
    with pytest.raises(PairError):
        fm.start(1.0)


def test_out_of_range_ids_are_refused() -> None:
    with pytest.raises(ValueError):
        machine(0, 0)
    with pytest.raises(ValueError):
        machine(101, 256)


def test_a_thawed_active_one_that_was_not_replaced_claims_again_after_a_negotiation() -> None:
    pair, a, b = a_active_b_standby()
    a.up = b.up = False  # both frozen (one machine, starved): nobody took over
    pair.run_until(8.0)
    a.up = b.up = True
    pair._act(a, a.fm.on_stall(pair.now))
    assert a.fm.role is Role.STANDBY
    pair.run_until(12.0)
    assert a.fm.role is Role.ACTIVE or b.fm.role is Role.ACTIVE
    assert pair.heartbeat_senders(since=11.0) in ({"A"}, {"B"})


def test_a_stall_means_nothing_to_a_standby() -> None:
    fm = machine(102, 1)
    fm.start(0.0)
    fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 0.1)
    assert fm.on_stall(5.0) == [] and fm.role is Role.STANDBY and fm.stalls == 0


# ------------------------------------------------------------------ the link


def test_a_standby_whose_cable_is_cut_is_isolated_sends_nothing_and_rejoins_as_standby() -> None:
    pair, a, b = a_active_b_standby()
    b.cut = True
    pair.run_until(8.0)
    assert b.fm.role is Role.ISOLATED and b.fm.negotiations == 0
    assert "cut off" in b.roles[-1][2]
    assert pair.pair_frames(since=5.0, sender="B") == 0  # no 72h, no 71h: it did not negotiate
    assert a.fm.role is Role.ACTIVE
    b.cut = False  # mended
    pair.run_until(12.0)
    assert (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY)
    assert [r for _, r, _ in b.roles[-3:]] == [Role.ISOLATED, Role.LISTENING, Role.STANDBY]
    assert pair.heartbeat_senders(since=5.0) == {"A"}


def test_an_active_one_whose_cable_is_cut_stands_down_and_never_fails_back() -> None:
    pair, a, b = a_active_b_standby()
    a.cut = True
    cut_at = pair.now
    pair.run_until(8.0)
    assert a.fm.role is Role.ISOLATED and a.fm.isolations == 1
    assert b.fm.role is Role.ACTIVE and b.fm.takeovers == 1
    stood_down = next(t for t, r, _ in a.roles if r is Role.ISOLATED)
    assert stood_down - cut_at <= TIMING.takeover_s + 2 * HEARTBEAT_S  # reported every period
    a.cut = False  # mended: A has the better priority, and stays out
    pair.run_until(20.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.ACTIVE)
    assert pair.heartbeat_senders(since=9.0) == {"B"}
    assert pair.sent("A", COB_ACTIVE_MASTER_RESPONSE, since=cut_at) == 0


def test_an_active_one_cut_while_its_nodes_seem_alive_yields_when_the_bus_returns() -> None:
    """Its nodes' supervision has not expired yet: it keeps mastering (into nothing), marked
    cut; when the bus returns and it meets the new active one it stands by, whatever its
    priority: no fail-back onto the member that was cut off."""
    pair, a, b = a_active_b_standby()
    a.nodes_alive = True
    a.cut = True
    pair.run_until(6.5)
    assert a.fm.role is Role.ACTIVE and a.fm.was_cut
    assert b.fm.role is Role.ACTIVE
    a.cut = False
    pair.run_until(7.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.ACTIVE)
    assert "no fail-back onto it" in next(why for t, r, why in a.roles if t >= 6.5)
    assert pair.heartbeat_senders(since=6.6) == {"B"}
    assert pair.sent("A", COB_ACTIVE_MASTER_RESPONSE, since=5.0) == 0


def test_an_active_one_that_loses_its_adapter_stands_down_at_once() -> None:
    pair, a, b = a_active_b_standby()
    a.cut = True  # an adapter lost: nothing in, nothing out, and the driver says down
    pair._act(a, a.fm.on_link(False, pair.now))
    assert a.fm.role is Role.ISOLATED and a.next_heartbeat_s == math.inf
    assert a.roles[-1][2] == "this gateway's CAN bus is down"
    pair.run_until(8.0)
    assert b.fm.role is Role.ACTIVE
    pair._act(a, a.fm.on_link(True, pair.now))  # reopened: it listens once it hears the bus
    a.cut = False
    pair.run_until(12.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.ACTIVE)


def test_a_standby_that_loses_its_adapter_is_isolated_and_back_joins_as_standby() -> None:
    pair, a, b = a_active_b_standby()
    b.cut = True
    pair._act(b, b.fm.on_link(False, pair.now))
    assert b.fm.role is Role.ISOLATED
    pair.run_until(8.0)
    assert b.fm.role is Role.ISOLATED  # it heard nothing while the link was down
    pair._act(b, b.fm.on_link(True, pair.now))
    b.cut = False
    pair.run_until(10.0)
    assert (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY)
    assert pair.pair_frames(since=5.0, sender="B") == 1  # its 73h when it listened again


def test_a_standby_whose_active_dies_on_a_silent_bus_cannot_tell_and_stays_isolated() -> None:
    """Every device talks only when asked (guarded): with the active one gone the standby
    hears nobody, exactly as with its own cable cut: it stays out until it hears the bus."""
    pair, a, b = a_active_b_standby()
    pair.devices = False
    a.up = False
    pair.run_until(10.0)
    assert b.fm.role is Role.ISOLATED and b.fm.negotiations == 0
    pair.devices = True  # a device talks (a boot-up, a heartbeat): the bus is there
    pair.run_until(12.0)
    assert b.fm.role is Role.ACTIVE


def test_a_lone_gateway_starting_on_a_silent_bus_claims_after_the_silent_time_and_keeps_it_while_heard() -> None:
    pair = Pair(devices=False)
    a = pair.add("A", node_id=101, priority=0)
    pair.run_until(TIMING.silent_s - 0.01)
    assert a.fm.role is Role.LISTENING  # its bus delivered nothing: it may be stalled
    pair.run_until(TIMING.silent_s + TIMING.slot_s(0, 101) + 0.01)
    assert a.fm.role is Role.ACTIVE  # nothing for silent_s: a silent bus, it claims
    pair.devices = True  # its devices answer the master: it keeps the bus
    pair.run_until(10.0)
    assert a.fm.role is Role.ACTIVE and a.fm.isolations == 0


def test_both_members_back_from_a_whole_bus_outage_find_each_other_by_their_own_heartbeats() -> None:
    pair, a, b = a_active_b_standby()
    pair.devices = False
    for gw in (a, b):
        pair._act(gw, gw.fm.on_link(False, pair.now))
    assert (a.fm.role, b.fm.role) == (Role.ISOLATED, Role.ISOLATED)
    for gw in (a, b):
        pair._act(gw, gw.fm.on_link(True, pair.now))
    pair.run_until(10.0)
    assert {a.fm.role, b.fm.role} == {Role.ACTIVE, Role.STANDBY}


# ------------------------------------------------------------------ duplicate ids


def test_a_member_with_the_id_of_a_standby_stays_out_and_the_active_one_keeps_the_bus() -> None:
    pair, a, b = a_active_b_standby()
    c = pair.add("C", node_id=102, priority=1)  # B's environment forgotten: B's id again
    pair.run_until(8.0)
    # the first to hear the other goes out and is silent from then on; the other stays standby
    out = c if c.fm.role is Role.DUPLICATE else b
    assert {b.fm.role, c.fm.role} == {Role.DUPLICATE, Role.STANDBY}
    assert a.fm.role is Role.ACTIVE
    assert out.fm.conflict == (
        "another device uses this gateway's pair id 102: heard a heartbeat on 0x766"
    )
    out_at = next(t for t, r, _ in out.roles if r is Role.DUPLICATE)
    assert {cob for t, s, cob, _ in pair.log if s == out.name and t > out_at} == set()
    assert pair.heartbeat_senders(since=5.0) == {"A"}


def test_an_active_member_that_hears_its_own_pair_id_keeps_the_bus_and_says_so_once() -> None:
    fm = active_machine()
    assert fm.on_frame(COB_HEARTBEAT + 101, b"\x05", 3.0) == [
        Notice(
            "notice",
            "duplicate",
            "pair: another device uses this gateway's pair id 101: heard a heartbeat on 0x765; "
            "this gateway keeps the bus",
        )
    ]
    fm.on_frame(COB_ACTIVE_MASTER_RESPONSE, bytes((3, 101)), 3.1)
    assert fm.role is Role.ACTIVE and fm.duplicates == 2


def test_a_foreign_logical_heartbeat_is_answered_with_at_most_three_claims_per_detect_cycle() -> None:
    fm = active_machine()
    sent: list[Send] = []
    t = 2.0
    while t < 12.0:  # a device stuck sending the logical master's heartbeat every 100 ms
        t += HEARTBEAT_S
        sent += [a for a in fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", t) if isinstance(a, Send)]
        sent += [a for a in fm.poll(t) if isinstance(a, Send)]
    claims = [a for a in sent if a.cob_id == COB_ACTIVE_MASTER_RESPONSE]
    assert fm.role is Role.ACTIVE and len(claims) == fm.duties.outclaims == 9  # 3 per 4 s
    assert [a for a in sent if a.cob_id == COB_DETECT_CAPABLE] == []  # no 75h: no master met


# ------------------------------------------------------------------ a third-party master


def test_a_better_third_party_master_makes_both_members_standby_in_a_handful_of_frames() -> None:
    pair = Pair()
    a = pair.add("A", node_id=101, priority=1, peer_id=102)
    pair.run_until(1.0)
    b = pair.add("B", node_id=102, priority=2, peer_id=101)
    pair.run_until(5.0)
    pair.add_third_party(node_id=5, priority=0)
    pair.run_until(7.0)
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.STANDBY)
    assert a.fm.third_party is not None and a.fm.third_party.node_id == 5
    assert pair.pair_frames(since=5.0) <= 10
    settled = pair.now
    pair.run_until(30.0)  # its heartbeat keeps both standby; its 76h every 4 s is all
    assert (a.fm.role, b.fm.role) == (Role.STANDBY, Role.STANDBY)
    assert pair.pair_frames(since=settled, sender="A") == 0
    assert pair.pair_frames(since=settled, sender="B") == 0
    assert pair.heartbeat_senders(since=settled) == set()


def test_a_worse_third_party_master_changes_nothing() -> None:
    pair = Pair()
    a = pair.add("A", node_id=101, priority=0, peer_id=102)
    pair.run_until(1.0)
    b = pair.add("B", node_id=102, priority=1, peer_id=101)
    pair.run_until(5.0)
    t = pair.add_third_party(node_id=5, priority=9)
    pair.run_until(30.0)
    assert (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY) and not t.active
    detect_checks = pair.sent("A", COB_FORCE_NEGOTIATION, since=5.0)
    assert detect_checks == 6  # A's 76h every 4 s
    assert pair.pair_frames(since=5.0) - detect_checks == 2  # T's 73h, A's 71h: nothing else
    assert pair.heartbeat_senders(since=5.0) == {"A"}


def test_every_role_change_and_every_answer_is_a_row_of_the_tables() -> None:
    assert set(DOES).isdisjoint(TRANSITIONS)
    assert {r for r, _ in TRANSITIONS} == set(Role) - {Role.DUPLICATE}
    fm = machine(101, 0)
    for name in DOES.values():
        on, attr = (fm.duties, name[7:]) if name.startswith("duties.") else (fm, name)
        assert callable(getattr(on, attr)), name


# ------------------------------------------------------------------ sequences of issue scale


def test_a_joining_standby_whose_bus_stalls_listens_until_it_delivers_and_never_negotiates() -> None:
    """Its process starts while the bus delivers nothing yet (a relay or a machine starved):
    the detection time counts from the first frame its bus delivers."""
    fm = machine(102, 1)
    sent = [a for a in fm.start(0.0) if isinstance(a, Send)]
    for t in (0.3, 0.5, 0.7, 0.87):
        fm.on_hearing(t, last_frame_s=None)
        sent += [a for a in fm.poll(t) if isinstance(a, Send)]
    assert fm.role is Role.LISTENING and sent == [Send("send", COB_ACTIVE_MASTER_REQUEST, b"")]
    fm.on_hearing(0.9, last_frame_s=0.9)  # the burst arrives: the active one's heartbeat in it
    fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 0.9)
    assert fm.role is Role.STANDBY and fm.negotiations == 0


def test_a_standby_takes_over_at_once_when_the_active_member_says_it_stopped_mastering() -> None:
    """A planned hand-over: the active member stops (SIGTERM) and its own heartbeat says it
    no longer masters the bus: no take-over time, no slot."""
    a = active_machine(peer_id=102)
    b = machine(102, 1, peer_id=101)
    b.start(0.0)
    b.on_frame(COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101)), 0.5)  # A's claim
    b.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 2.0)
    assert b.on_peer_heartbeat(bytes((a.own_state,)), 2.05) == []  # A says: active
    assert b.role is Role.STANDBY and b.peer_role(2.05) == "active"
    a.on_peer_heartbeat(bytes((b.own_state,)), 2.06)
    assert a.peer_role(2.06) == "standby"
    (change,) = a.hand_over(2.08)
    assert isinstance(change, RoleChanged) and change.role is Role.STANDBY and not change.fresh
    actions = b.on_peer_heartbeat(bytes((a.own_state,)), 2.081)  # A says: not active
    assert b.role is Role.ACTIVE and Send("send", COB_ACTIVE_MASTER_RESPONSE, bytes((1, 102))) in actions
    changes = [x for x in actions if isinstance(x, RoleChanged)]
    assert b.takeovers == 1 and "handed the bus over" in changes[0].reason
    # A, standing by, hears B's claim and logical heartbeat: it stays standby
    a.on_frame(COB_ACTIVE_MASTER_RESPONSE, bytes((1, 102)), 2.082)
    a.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 2.09)
    assert a.role is Role.STANDBY


def test_a_member_whose_driver_says_it_cannot_send_stands_down_and_comes_back_a_fresh_joiner() -> None:
    fm = active_machine()
    (change,) = fm.on_link(True, 3.0, sending=False)  # bus off, error passive, queue full
    assert isinstance(change, RoleChanged) and change.role is Role.ISOLATED and change.fresh
    assert "cannot send" in change.reason and fm.own_state == 0x04
    assert fm.on_hearing(3.5, last_frame_s=3.5) == []  # it hears, but still cannot send
    assert fm.on_link(True, 4.0, sending=True) == []
    actions = fm.on_hearing(4.1, last_frame_s=4.1)
    assert fm.role is Role.LISTENING and Send("send", COB_ACTIVE_MASTER_REQUEST, b"") in actions
    fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", 4.2)  # the other took over meanwhile
    assert fm.role is Role.STANDBY  # no fail-back onto it


def test_an_active_one_stands_by_at_once_on_a_better_claim_the_slots_decide_nothing() -> None:
    """Slots that do not follow the priority order (which check refuses) decide nothing: the
    machine compares (priority, node id)."""
    a = active_machine(node_id=120, priority=0)
    b = active_machine(node_id=3, priority=1)  # its slot (206 ms) ends before A's (240 ms)
    for x, y in ((a, b), (b, a)):
        for act in x.duties.answer(3.0):
            assert isinstance(act, Send)
            y.on_frame(act.cob_id, act.data, 3.0)
    assert (a.role, b.role) == (Role.ACTIVE, Role.STANDBY)


def test_a_lost_claim_of_a_negotiation_leaves_two_actives_for_one_frame_only() -> None:
    """The winner's claim and its first logical heartbeat lost (a glitch at its claim): the
    loser claims at the end of its slot, the winner answers the worse claim with its own, the
    loser stands by on it."""
    pair = Pair()
    a = pair.add("A", node_id=101, priority=0)
    b = pair.add("B", node_id=102, priority=1)
    lost = {"done": False}
    send = pair._send

    def losing(sender: Gateway, cob_id: int, data: bytes) -> None:
        if sender is a and cob_id == COB_ACTIVE_MASTER_RESPONSE and not lost["done"]:
            lost["done"] = True
            lost["at"] = pair.now  # type: ignore[assignment]
        if sender is a and lost["done"] and pair.now == lost.get("at"):
            pair.log.append((pair.now, "A", cob_id, data))
            return  # no one hears it
        send(sender, cob_id, data)

    pair._send = losing  # type: ignore[method-assign]
    pair.run_until(5.0)
    assert lost["done"] and (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY)
    b_active = [t for t, r, _ in b.roles if r is Role.ACTIVE]
    b_out = [t for t, r, _ in b.roles if r is Role.STANDBY and b_active and t >= b_active[0]]
    # B stood by on A's next logical heartbeat, within its slot; had it claimed, A's answer
    # would have made it stand by within a frame, not a detect cycle
    assert not b_active or (b_out and b_out[0] - b_active[0] <= HEARTBEAT_S)
    assert pair.heartbeat_senders(since=0.7) == {"A"}


def test_a_standby_on_a_bus_of_rarely_talking_devices_waits_for_them_instead_of_isolating() -> None:
    """Devices with 1 s heartbeats: after the active one dies the standby waits for a frame
    until a device must have talked, then takes over; check's worst take-over holds."""
    slow = PairTiming(takeover_s=0.3, detect_s=0.3, heartbeat_s=HEARTBEAT_S, talk_s=1.0)
    fm = machine(102, 1, timing=slow)
    fm.start(0.0)
    fm.on_hearing(0.05, last_frame_s=0.05)
    t, last_master = 0.1, 0.0
    while t < 3.0:
        fm.on_frame(COB_HEARTBEAT + MASTER, b"\x05", t)
        last_master = t
        t = round(t + HEARTBEAT_S, 3)
        fm.poll(t)
    assert fm.role is Role.STANDBY
    device_at = last_master + 0.95  # the device's next heartbeat: the bus is alive
    t = last_master
    while t < device_at:
        t = round(t + 0.025, 3)
        fm.on_hearing(t, last_frame_s=None if t < device_at else device_at)
        fm.poll(t)
    assert fm.role is Role.NEGOTIATING and fm.isolations == 0
    fm.poll(t + slow.slot_s(1, 102))
    worst = slow.worst_takeover_s(1, 102)
    assert fm.role is Role.ACTIVE and worst is not None
    assert t + slow.slot_s(1, 102) - last_master <= worst - slow.heartbeat + 0.03
