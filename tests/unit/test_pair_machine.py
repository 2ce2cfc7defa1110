"""The role machine of a hot-standby pair (CiA 302-2 flying master), on a fake bus and clock.

A ``Pair`` joins machines by a fake bus: a frame one sends reaches every other machine at the
same instant; an active machine's gateway produces the logical heartbeat every period. Gateways
can be killed (silent, gone), frozen (silent, then back with their state) and restarted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest

from gateway.bus.pair.flying_master import (
    COB_ACTIVE_MASTER_REQUEST,
    COB_ACTIVE_MASTER_RESPONSE,
    COB_FORCE_NEGOTIATION,
    COB_HEARTBEAT,
    COB_NEGOTIATION_REQUEST,
    TRANSITIONS,
    FlyingMaster,
    PairError,
    PairTiming,
    Role,
    RoleChanged,
    Send,
)

MASTER = 100
HEARTBEAT_S = 0.1
TIMING = PairTiming(
    takeover_s=3 * HEARTBEAT_S, detect_s=3 * HEARTBEAT_S, claim_period_s=HEARTBEAT_S
)


def machine(node_id: int, priority: int, timing: PairTiming = TIMING) -> FlyingMaster:
    return FlyingMaster(node_id=node_id, priority=priority, master_node_id=MASTER, timing=timing)


@dataclass
class Gateway:
    name: str
    fm: FlyingMaster
    up: bool = True
    next_heartbeat_s: float = math.inf
    roles: list[tuple[float, Role, str]] = field(default_factory=list)


@dataclass
class Pair:
    """Discrete-event run of several machines on one fake bus."""

    gateways: dict[str, Gateway] = field(default_factory=dict)
    now: float = 0.0
    log: list[tuple[float, str, int, bytes]] = field(default_factory=list)  # (t, sender, cob, data)

    def add(self, name: str, node_id: int, priority: int) -> Gateway:
        gw = Gateway(name, machine(node_id, priority))
        self.gateways[name] = gw
        self._act(gw, gw.fm.start(self.now))
        return gw

    def restart(self, name: str) -> Gateway:
        old = self.gateways[name].fm
        return self.add(name, old.node_id, old.priority)

    def _send(self, sender: Gateway, cob_id: int, data: bytes) -> None:
        self.log.append((self.now, sender.name, cob_id, data))
        for gw in self.gateways.values():
            if gw is not sender and gw.up:
                self._act(gw, gw.fm.on_frame(cob_id, data, self.now))

    def _act(self, gw: Gateway, actions: list) -> None:
        for a in actions:
            if isinstance(a, Send):
                self._send(gw, a.cob_id, a.data)
            elif isinstance(a, RoleChanged):
                gw.roles.append((self.now, a.role, a.reason))
                if a.role is Role.ACTIVE:
                    gw.next_heartbeat_s = self.now  # the logical heartbeat starts at once
                else:
                    gw.next_heartbeat_s = math.inf

    def run_until(self, t_end: float) -> None:
        while True:
            events = []
            for gw in self.gateways.values():
                if not gw.up:
                    continue
                d = gw.fm.next_deadline_s()
                if d is not None:
                    events.append((d, 0, gw))
                events.append((gw.next_heartbeat_s, 1, gw))
            if not events:
                self.now = t_end
                return
            t, kind, gw = min(events, key=lambda e: (e[0], e[1], e[2].name))
            if t > t_end:
                self.now = t_end
                return
            self.now = max(self.now, t)
            if kind == 0:
                self._act(gw, gw.fm.poll(self.now))
            else:
                gw.next_heartbeat_s = self.now + HEARTBEAT_S
                self._send(gw, COB_HEARTBEAT + MASTER, b"\x05")

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

    def sent(self, sender: str, cob_id: int) -> int:
        return sum(1 for _, s, c, _ in self.log if s == sender and c == cob_id)


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
    assert {c for _, s, c, _ in pair.log if s == "B"} == {COB_ACTIVE_MASTER_REQUEST}
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
    # counted from A's last frame (its heartbeat or its claim, at most a claim period apart)
    silent_s = TIMING.takeover_s + TIMING.slot_s(1, 102)
    assert silent_s <= gap <= silent_s + TIMING.claim_period_s
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


def test_two_actives_that_hear_each_other_resolve_by_priority_in_one_claim_period() -> None:
    pair = Pair()
    a = pair.add("A", node_id=101, priority=0)
    pair.run_until(1.0)
    b = pair.add("B", node_id=102, priority=1)
    pair.run_until(2.0)
    # a partition ends: both believed themselves active
    b.fm.role = Role.ACTIVE
    b.fm._deadline_s = pair.now
    pair.run_until(2.0 + HEARTBEAT_S)
    assert (a.fm.role, b.fm.role) == (Role.ACTIVE, Role.STANDBY)


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
    actions = fm.poll(1.0 + TIMING.takeover_s)
    assert fm.role is Role.NEGOTIATING
    assert Send("send", COB_NEGOTIATION_REQUEST, b"") in actions


# ------------------------------------------------------------------ answers and edges


@pytest.mark.parametrize(
    "cob_id", [COB_ACTIVE_MASTER_REQUEST, COB_NEGOTIATION_REQUEST, COB_FORCE_NEGOTIATION]
)
def test_the_active_one_answers_requests_with_its_claim(cob_id: int) -> None:
    fm = machine(101, 0)
    fm.start(0.0)
    fm.poll(10.0)
    fm.poll(20.0)
    assert fm.role is Role.ACTIVE
    assert fm.on_frame(cob_id, b"", 21.0) == [
        Send("send", COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101)))
    ]
    assert fm.role is Role.ACTIVE


def test_our_own_claim_and_heartbeat_echoed_by_the_bus_change_nothing() -> None:
    fm = machine(101, 0)
    fm.start(0.0)
    fm.poll(10.0)
    fm.poll(20.0)
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
