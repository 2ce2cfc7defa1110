"""The pair member on a fake event loop and clock: it claims when alone, and an active member
that did not run for longer than the take-over time (a frozen process) stands by before it acts."""

from __future__ import annotations

from typing import Any

from canopen_gateway.bus.pair.flying_master import (
    COB_ACTIVE_MASTER_REQUEST,
    COB_ACTIVE_MASTER_RESPONSE,
    Role,
    RoleChanged,
)
from canopen_gateway.bus.pair.member import PairMember
from tests.helpers import make_config

OWN = 0x700 + 101
LOGICAL = 0x700 + 100


class FakeHandle:
    def __init__(self, loop: FakeLoop, when: float, fn: Any):
        self.loop, self.when, self.fn, self.cancelled = loop, when, fn, False

    def cancel(self) -> None:
        self.cancelled = True


class FakeLoop:
    """``time`` and ``call_at`` of an asyncio loop; ``run_until`` fires what is due."""

    def __init__(self) -> None:
        self.now = 0.0
        self.timers: list[FakeHandle] = []

    def time(self) -> float:
        return self.now

    def call_at(self, when: float, fn: Any) -> FakeHandle:
        h = FakeHandle(self, when, fn)
        self.timers.append(h)
        return h

    def run_until(self, t: float) -> None:
        while True:
            due = [h for h in self.timers if not h.cancelled and h.when <= t]
            if not due:
                self.now = t
                return
            h = min(due, key=lambda h: h.when)
            self.timers.remove(h)
            self.now = max(self.now, h.when)
            h.fn()


def member(
    devices: bool = True, **redundancy: object
) -> tuple[PairMember, FakeLoop, list[tuple[int, bytes]], list[RoleChanged]]:
    """A member on a fake loop; ``devices``: the bus carries frames of others (the time of the
    last frame received is the loop's time), else it is silent."""
    cfg = make_config(
        [],
        master={
            "node_id": 100,
            "heartbeat_ms": 100,
            "redundancy": {"node_id": 101, **redundancy},
        },
    )
    loop = FakeLoop()
    sent: list[tuple[int, bytes]] = []
    roles: list[RoleChanged] = []
    m = PairMember(
        cfg,
        lambda c, d: sent.append((c, d)),
        loop.time,
        roles.append,
        last_frame_s=(lambda: loop.now) if devices else (lambda: None),
    )
    m.start(loop)  # type: ignore[arg-type]
    return m, loop, sent, roles


def test_alone_it_asks_once_then_claims_after_its_time_slot() -> None:
    m, loop, sent, roles = member()
    assert sent[0] == (COB_ACTIVE_MASTER_REQUEST, b"")
    loop.run_until(1.0)
    assert m.machine.role is Role.ACTIVE
    assert (COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101))) in sent
    assert [r.role for r in roles] == [Role.NEGOTIATING, Role.ACTIVE]


def test_its_own_heartbeat_goes_out_every_period_and_never_with_a_duplicate_id() -> None:
    m, loop, sent, _roles = member()
    loop.run_until(0.95)
    # at 0.2, 0.3 .. 0.9, its role in the state byte: pre-operational while it listens and
    # negotiates, operational once active
    own = [d for c, d in sent if c == OWN]
    assert len(own) == 8 and set(own) == {b"\x7f", b"\x05"} and own[-1] == b"\x05"
    m.on_frame(COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101)), loop.now)  # ours, from another
    assert m.machine.role is Role.ACTIVE  # it was mastering: it keeps the bus
    m2, loop2, sent2, _ = member()
    loop2.run_until(0.05)
    m2.on_frame(OWN, b"\x05", loop2.now)  # another device's heartbeat on our own id
    assert m2.role == "duplicate" and m2.conflict is not None
    sent2.clear()
    loop2.run_until(5.0)
    assert sent2 == []  # out: nothing on the bus


def test_an_active_member_that_did_not_run_stands_by_at_its_next_event() -> None:
    m, loop, sent, roles = member()
    loop.run_until(1.0)
    assert m.machine.role is Role.ACTIVE
    loop.now = 3.0  # the process was frozen for 2 s: no timer ran
    m.check()
    assert m.machine.role is Role.STANDBY
    assert roles[-1].reason.startswith("this gateway did not run")


def test_an_active_member_that_runs_on_time_never_stalls() -> None:
    m, loop, _sent, _roles = member()
    loop.run_until(60.0)  # its own heartbeat every 100 ms keeps it running
    m.check()
    assert m.machine.role is Role.ACTIVE and m.machine.stalls == 0


def test_a_member_whose_bus_goes_down_is_isolated_and_back_it_listens_first() -> None:
    m, loop, sent, roles = member()
    loop.run_until(1.0)
    m.on_link("down")
    assert m.role == "isolated" and roles[-1].reason == "this gateway's CAN bus is down"
    assert roles[-1].fresh  # back, it listens as a fresh joiner
    m.on_link("ok")
    loop.run_until(1.2)  # frames are heard again
    assert m.role == "listening" and sent[-1] != (COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101)))


def test_a_standby_rearms_its_timer_once_per_take_over_time_not_per_heartbeat_heard() -> None:
    m, loop, _sent, _roles = member()
    t = 0.0
    while t < 10.0:  # the active master's heartbeat every 100 ms
        t = round(t + 0.1, 3)
        loop.run_until(t)
        m.on_frame(LOGICAL, b"\x05", t)
    assert m.role == "standby"
    # it fires when the deadline it was armed for comes, then arms the one due by then: at
    # most once per (take-over time - heartbeat period), not once per heartbeat heard (100)
    assert m.rearms <= 10.0 / (0.3 - 0.1) + 3


def test_nothing_heard_of_the_peer_for_long_is_one_warning(caplog: Any) -> None:
    m, loop, _sent, _roles = member(peer_node_id=102)
    with caplog.at_level("WARNING", logger="gateway.master"):
        loop.run_until(9.9)
        assert not m.peer_silent
        loop.run_until(30.0)
    assert m.peer_silent
    lines = [r.getMessage() for r in caplog.records if "nothing heard of the peer" in r.getMessage()]
    assert lines == [
        "pair: nothing heard of the peer (pair id 102) for 10 s: it is stopped or cut off, or "
        "the two members are not on one bus (interface virtual is private to each process)"
    ]
    m.on_peer_heartbeat(b"\x7f", loop.now)
    loop.run_until(30.2)
    assert not m.peer_silent
