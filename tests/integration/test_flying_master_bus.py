"""The third-party CiA 302-2 flying master (``tests/flying_master_302.py``) on the pair's test bus
(``tests/pair_bus.py``), against itself: two of them agree on one active master, with a handful
of frames, and the relay's record says who sent what."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.flying_master_302 import ACTIVE, SLAVE, FlyingMaster302, Timing302
from tests.helpers import wait_until_sync
from tests.pair_bus import PairBus

# timings with room for a loaded machine (an answer to 73h within 1 s, slots 1 s apart by
# priority); no periodic 76h within a test: the exchange counted below is the negotiation alone
FAST = Timing302(
    detect_timeout_ms=1000,
    start_delay_ms=100,
    priority_slot_ms=1000,
    heartbeat_ms=200,
    detect_cycle_ms=60_000,
)
NEGOTIATION = range(0x71, 0x77)


@pytest.fixture
def bus() -> Iterator[PairBus]:
    with PairBus() as b:
        yield b


def test_two_flying_masters_on_the_bus_agree_on_the_better_one(bus: PairBus) -> None:
    worse = FlyingMaster302(bus.open_bus("worse"), node_id=2, priority=1, timing=FAST).start()
    better = FlyingMaster302(bus.open_bus("better"), node_id=9, priority=0, timing=FAST)
    try:
        wait_until_sync(lambda: worse.state == ACTIVE, 10.0, "the worse master alone active")
        bus.wait_for(lambda f: f.sender == "worse" and f.cob_id == 0x702)  # its heartbeat
        mark = len(bus.frames)
        better.start()
        wait_until_sync(
            lambda: (better.state, worse.state) == (ACTIVE, SLAVE), 10.0, "one active master"
        )
        bus.wait_for(lambda f: f.sender == "better" and f.cob_id == 0x709, after=mark)
        assert worse.machine.active_master == (0, 9)
        after = [(f.sender, f.cob_id) for f in bus.frames[mark:] if f.cob_id in NEGOTIATION]
        # 73h asked, the worse one's one 71h answered, 76h + 72h forced, one claim: five frames
        assert after == [
            ("better", 0x73), ("worse", 0x71), ("better", 0x76), ("better", 0x72), ("better", 0x71)
        ]
        assert better.sent[0x71] == 1 and worse.sent[0x71] == 2
        assert all(f.delivered for f in bus.frames)
        assert not (better.errors or worse.errors)
    finally:
        better.stop()
        worse.stop()


def test_a_cut_flying_master_makes_itself_active_while_deaf(bus: PairBus) -> None:
    """What a shipped flying master does when its cable is cut: it hears no 71h and claims (the
    pair must not take its frames for a live master: they reach no one)."""
    a = FlyingMaster302(bus.open_bus("a"), node_id=1, timing=FAST).start()
    b = FlyingMaster302(bus.open_bus("b"), node_id=2, timing=FAST)
    try:
        wait_until_sync(lambda: a.state == ACTIVE, 10.0, "a active")
        bus.cut("b")
        b.start()
        wait_until_sync(lambda: b.state == ACTIVE, 10.0, "b active though cut")
        assert a.state == ACTIVE
        assert bus.wait_for(lambda f: f.sender == "b" and f.cob_id == 0x71).delivered is False
        assert a.sent[0x71] == 1  # a heard no claim: it stays active, as b does
    finally:
        a.stop()
        b.stop()
