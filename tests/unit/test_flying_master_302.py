"""The third-party CiA 302-2 flying master of the pair's tests (``tests/flying_master_302.py``),
against itself on a fake clock and a fake bus (every frame reaches every other master at once,
never its sender)."""

from __future__ import annotations

import math

from tests.flying_master_302 import (
    ACTIVE,
    NEGOTIATING,
    SLAVE,
    FlyingMaster302Machine,
    Timing302,
)

T = Timing302()


class FakeBus:
    """Machines on one bus, driven by a discrete-event loop on a fake clock."""

    def __init__(self, *machines: FlyingMaster302Machine) -> None:
        self.machines = list(machines)
        self.now = 0.0
        self.log: list[tuple[float, int, int, bytes]] = []  # (t, sender node id, cob_id, data)

    def start(self, m: FlyingMaster302Machine) -> None:
        self.deliver(m, m.start(self.now))

    def deliver(self, sender: FlyingMaster302Machine, frames: list[tuple[int, bytes]]) -> None:
        for cob_id, data in frames:
            self.log.append((self.now, sender.node_id, cob_id, data))
            for m in self.machines:
                if m is not sender:
                    self.deliver(m, m.on_frame(cob_id, data, self.now))

    def run_until(self, t_end: float) -> None:
        while True:
            due = [m.deadline for m in self.machines if m.deadline is not None]
            if not due or min(due) > t_end:
                self.now = t_end
                return
            self.now = min(due)
            for m in self.machines:
                if m.deadline is not None and m.deadline <= self.now:
                    self.deliver(m, m.on_time(self.now))

    def sent(self, node_id: int, cob_id: int | None = None) -> list[tuple[float, int, int, bytes]]:
        return [e for e in self.log if e[1] == node_id and (cob_id is None or e[2] == cob_id)]


def test_a_lone_master_asks_negotiates_and_claims_after_its_slot() -> None:
    m = FlyingMaster302Machine(node_id=5, priority=1)
    bus = FakeBus(m)
    bus.start(m)
    bus.run_until(math.nextafter(0.5, 0))
    assert bus.log == []  # 1F90h:02: silent for 500 ms
    bus.run_until(0.5)
    assert [e[2] for e in bus.log] == [0x73]
    bus.run_until(0.6)  # 1F90h:01: nobody answered within 100 ms
    assert [e[2] for e in bus.log] == [0x73, 0x72]
    slot = 1 * 1.5 + 5 * 0.010  # priority x 1F90h:04 + node id x 1F90h:05
    bus.run_until(math.nextafter(0.6 + slot, 0))
    assert m.state == NEGOTIATING
    bus.run_until(0.6 + slot)
    assert m.state == ACTIVE
    assert bus.log[2][2:] == (0x71, bytes([1, 5]))
    assert bus.log[3][2:] == (0x705, b"\x05")


def test_the_active_master_checks_for_others_with_76h_every_detect_cycle() -> None:
    m = FlyingMaster302Machine(node_id=1, timing=Timing302(heartbeat_ms=1000))
    bus = FakeBus(m)
    bus.start(m)
    bus.run_until(20.0)
    claimed = bus.sent(1, 0x71)[0][0]
    assert [round(e[0] - claimed, 6) for e in bus.sent(1, 0x76)] == [4.0, 8.0, 12.0, 16.0]
    assert len(bus.sent(1, 0x701)) == 20  # its heartbeat every second while active


def test_two_masters_agree_on_the_better_one_whichever_starts_first() -> None:
    better = FlyingMaster302Machine(node_id=9, priority=0)
    worse = FlyingMaster302Machine(node_id=2, priority=1)
    bus = FakeBus(worse, better)
    bus.start(worse)
    bus.run_until(10.0)  # the worse one alone: active
    assert worse.state == ACTIVE
    bus.start(better)
    bus.run_until(30.0)
    assert (better.state, worse.state) == (ACTIVE, SLAVE)
    assert worse.active_master == (0, 9)
    # the better one asked (73h), heard the worse claim (71h) and forced a negotiation once
    assert [e[2] for e in bus.sent(9) if e[2] in range(0x71, 0x77)][:4] == [0x73, 0x76, 0x72, 0x71]
    assert len(bus.sent(9, 0x72)) == 1


def test_two_masters_starting_together_negotiate_once() -> None:
    a = FlyingMaster302Machine(node_id=3, priority=1)
    b = FlyingMaster302Machine(node_id=4, priority=1)
    bus = FakeBus(a, b)
    bus.start(a)
    bus.start(b)
    bus.run_until(12.0)
    assert (a.state, b.state) == (ACTIVE, SLAVE)  # equal priority: the lower node id
    assert len([e for e in bus.log if e[2] == 0x71]) == 1


def test_the_active_master_answers_73h_with_one_71h_and_75h_with_74h() -> None:
    m = FlyingMaster302Machine(node_id=7, priority=2)
    m.start(0.0)
    assert m.on_frame(0x75, b"", 0.1) == [(0x74, bytes([2, 7]))]  # also before it is active
    for t in (0.5, 0.6, 10.0):
        m.on_time(t)
    assert m.state == ACTIVE
    assert m.on_frame(0x73, b"", 10.0) == [(0x71, bytes([2, 7]))]
    assert m.on_frame(0x75, b"", 10.0) == [(0x74, bytes([2, 7]))]


def test_the_active_master_forces_a_worse_claim_and_yields_to_a_better_one() -> None:
    m = FlyingMaster302Machine(node_id=7, priority=1)
    m.start(0.0)
    for t in (0.5, 0.6, 10.0):
        m.on_time(t)
    assert m.on_frame(0x71, bytes([2, 1]), 11.0) == [(0x76, b""), (0x72, b"")]
    assert m.state == NEGOTIATING
    m.on_time(11.0 + m.slot_s)
    assert m.state == ACTIVE
    assert m.on_frame(0x71, bytes([1, 3]), 20.0) == []
    assert (m.state, m.active_master) == (SLAVE, (1, 3))


def test_76h_makes_only_the_active_master_negotiate() -> None:
    active = FlyingMaster302Machine(node_id=1)
    slave = FlyingMaster302Machine(node_id=2, priority=1)
    for m in (active, slave):
        m.start(0.0)
    for t in (0.5, 0.6, 1.0):
        active.on_time(t)
    slave.on_time(0.5)
    slave.on_frame(0x71, bytes([0, 1]), 0.55)
    assert (active.state, slave.state) == (ACTIVE, SLAVE)
    assert active.on_frame(0x76, b"", 2.0) == []
    assert slave.on_frame(0x76, b"", 2.0) == []
    assert (active.state, slave.state) == (NEGOTIATING, SLAVE)
