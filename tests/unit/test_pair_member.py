"""The pair member on a fake event loop and clock: it claims when alone, and an active member
that did not run for longer than the take-over time (a frozen process) stands by before it acts."""

from __future__ import annotations

from typing import Any

from gateway.bus.pair.flying_master import (
    COB_ACTIVE_MASTER_REQUEST,
    COB_ACTIVE_MASTER_RESPONSE,
    Role,
    RoleChanged,
)
from gateway.bus.pair.member import PairMember
from tests.helpers import make_config


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


def member() -> tuple[PairMember, FakeLoop, list[tuple[int, bytes]], list[RoleChanged]]:
    cfg = make_config(
        [],
        master={"node_id": 100, "heartbeat_ms": 100, "redundancy": {"node_id": 101}},
    )
    loop = FakeLoop()
    sent: list[tuple[int, bytes]] = []
    roles: list[RoleChanged] = []
    m = PairMember(cfg, lambda c, d: sent.append((c, d)), loop.time, roles.append)
    m.start(loop)  # type: ignore[arg-type]
    return m, loop, sent, roles


def test_alone_it_asks_once_then_claims_after_its_time_slot() -> None:
    m, loop, sent, roles = member()
    assert sent == [(COB_ACTIVE_MASTER_REQUEST, b"")]
    loop.run_until(1.0)
    assert m.machine.role is Role.ACTIVE
    assert (COB_ACTIVE_MASTER_RESPONSE, bytes((0, 101))) in sent
    assert [r.role for r in roles] == [Role.NEGOTIATING, Role.ACTIVE]


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
    loop.run_until(60.0)  # its claim timer every 100 ms keeps it running
    m.check()
    assert m.machine.role is Role.ACTIVE and m.machine.stalls == 0
