"""The publishing threads (``zenoh_bridge/sender.py``): a writer's wake-ups coalesce into one
queued flush, a mark made while a flush runs gets a flush of its own, flushes go out once per
``batch_s`` window while marks keep coming (a fake clock), what is queued goes out
in order, stopping publishes what was queued; and in a running gateway every value put happens
on ``zenoh-publish``, never on the CAN reader, and an event put that blocks (congestion control
BLOCK on a congested link) does not hold the values back."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from canopen_gateway.runtime.threads import ThreadRegistry
from canopen_gateway.zenoh_bridge.sender import EVENT_WAIT_S, WITHHELD, ZenohSender
from tests.helpers import gateway_of, make_config, wait_until, wait_until_sync

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


class Pub:
    def __init__(self, name: str, log: list[str]) -> None:
        self.name = name
        self.log = log

    def put(self, payload: bytes, timestamp: Any = None) -> None:
        self.log.append(self.name)


def test_wake_ups_before_the_flush_runs_coalesce_into_one_flush() -> None:
    log: list[str] = []
    sender = ZenohSender(ThreadRegistry(), "zenoh-publish", lambda: log.append("flush"))
    for _ in range(100):  # a hundred bursts end before the thread gets to run
        sender.wake_values()
    assert sender.queue.qsize() == 1
    sender.start()
    sender.stop()  # a last flush, then the end
    assert log == ["flush", "flush"]


def test_a_mark_made_while_a_flush_runs_gets_a_flush_of_its_own() -> None:
    """The flag is cleared before the flush takes the marks: a writer that marks during the
    flush (its mark may miss the marks taken) queues the next one."""
    flushed = threading.Event()
    calls: list[int] = []
    sender: ZenohSender

    def flush() -> None:
        calls.append(len(calls))
        if len(calls) == 1:
            sender.wake_values()  # the reader ends a burst while the first flush runs
        else:
            flushed.set()

    sender = ZenohSender(ThreadRegistry(), "zenoh-publish", flush)
    sender.start()
    sender.wake_values()
    assert flushed.wait(10)
    sender.stop()
    assert calls[:2] == [0, 1]


class FakeClock:
    """The publisher's clock: it moves only when the publisher waits (by the time waited) or
    when the test moves it."""

    def __init__(self) -> None:
        self.now = 100.0
        self.waits: list[float] = []

    def __call__(self) -> float:
        return self.now

    def wait(self, seconds: float) -> None:
        self.waits.append(seconds)
        self.now += seconds


def test_while_marks_keep_coming_a_flush_goes_out_every_batch_window() -> None:
    """Sustained load: the writer wakes the publisher again while each flush runs (the reader
    every few frames of a backlog it never gets to the end of). Flushes start exactly one
    window apart: at most one per window, and never none."""
    clock = FakeClock()
    times: list[float] = []
    done = threading.Event()
    sender: ZenohSender

    def flush() -> None:
        times.append(clock.now)
        clock.now += 0.0003  # the flush takes 0.3 ms
        if len(times) < 10:
            sender.wake_values()  # marks keep coming
        else:
            done.set()

    sender = ZenohSender(
        ThreadRegistry(), "zenoh-publish", flush, batch_s=0.001, clock=clock, wait=clock.wait
    )
    sender.start()
    sender.wake_values()
    assert done.wait(10)
    sender.stop()
    assert times[:10] == pytest.approx([100.0 + 0.001 * i for i in range(10)])
    assert clock.waits[:9] == pytest.approx([0.0007] * 9)


def test_a_wake_up_after_a_quiet_window_flushes_at_once() -> None:
    clock = FakeClock()
    times: list[float] = []
    flushed = threading.Semaphore(0)
    sender = ZenohSender(
        ThreadRegistry(),
        "zenoh-publish",
        lambda: (times.append(clock.now), flushed.release()),
        batch_s=0.001,
        clock=clock,
        wait=clock.wait,
    )
    sender.start()
    sender.wake_values()
    assert flushed.acquire(timeout=10)
    clock.now += 0.005  # quiet for five windows
    sender.wake_values()
    assert flushed.acquire(timeout=10)
    sender.stop()
    assert times[:2] == [100.0, 100.005]
    assert clock.waits == []


def test_stopping_ends_a_window_being_waited_for_and_publishes_the_marks() -> None:
    """The real wait (no fake): a window of an hour does not hold ``stop``; the last flush
    publishes what was marked."""
    flushes: list[str] = []
    sender = ZenohSender(
        ThreadRegistry(), "zenoh-publish", lambda: flushes.append("flush"), batch_s=3600.0
    )
    sender.start()
    sender.wake_values()  # flushes at once: the window starts
    wait_until_sync(lambda: flushes == ["flush"], 10, "the first flush")
    sender.wake_values()  # waits for the window's end
    sender.stop(timeout_s=30)
    assert sender.thread is None and flushes[-1] == "flush" and len(flushes) >= 2


def publishers(log: list[str], *names: str) -> dict[str, Any]:
    return {n: Pub(n, log) for n in names}


def test_events_and_flushes_go_out_in_the_order_they_were_queued() -> None:
    log: list[str] = []
    pubs = publishers(log, "state 1", "emcy 1", "state 2")
    sender = ZenohSender(ThreadRegistry(), "zenoh-publish", lambda: log.append("flush"), pub_of=pubs.get)
    sender.put_event("state 1", b"{}", 1)
    sender.wake_values()
    sender.put_event("emcy 1", b"{}", 2)
    sender.put_event("state 2", b"{}", 3)
    sender.start()
    sender.stop()
    assert log == ["state 1", "flush", "emcy 1", "state 2", "flush"]
    assert sender.sent == 3 and sender.failed == 0


def test_a_failing_event_put_is_counted_and_the_thread_goes_on() -> None:
    log: list[str] = []

    class Failing:
        def put(self, payload: bytes, timestamp: Any = None) -> None:
            raise RuntimeError("network gone")

    threads = ThreadRegistry()
    pubs = {"failing": Failing(), "state": Pub("state", log)}
    sender = ZenohSender(threads, "zenoh-events", lambda: log.append("flush"), pub_of=pubs.get)
    sender.put_event("failing", b"{}", 1)
    sender.put_event("state", b"{}", 2)
    sender.start()
    sender.stop()
    assert sender.failed == 1 and sender.sent == 1
    assert log == ["state", "flush"]
    assert threads.failures() == {}


def test_an_event_waits_for_its_commit_at_most_the_bound_then_goes_out_counted() -> None:
    """The live path never waits for the disk: an event waits for its journal ticket until
    EVENT_WAIT_S after it was made (a fake clock), then is published and counted."""
    log: list[str] = []
    now = [100.0]
    waits: list[tuple[int, float]] = []
    sender = ZenohSender(
        ThreadRegistry(), "zenoh-events", clock=lambda: now[0], pub_of=publishers(log, "emcy").get
    )

    def wait(ticket: int, timeout_s: float) -> bool:
        waits.append((ticket, timeout_s))
        if ticket == 1:
            return True  # committed in time
        now[0] += timeout_s  # the disk stalls from ticket 2 on
        return False

    unjournaled: list[int] = []
    sender.journal_wait = wait
    sender.on_unjournaled = lambda: unjournaled.append(1)
    for ticket in (1, 2, 3, 0):  # 0: no journal entry, not waited for
        sender.put_event("emcy", b"{}", ticket, ticket=ticket)
    sender.start()
    sender.stop()
    assert log == ["emcy"] * 4 and len(unjournaled) == 2
    # made at once: behind a stalled disk a burst waits the bound once, not once each
    assert waits == [(1, pytest.approx(EVENT_WAIT_S)), (2, pytest.approx(EVENT_WAIT_S)), (3, 0.0)]


def test_events_made_without_a_session_go_out_in_order_once_it_is_open() -> None:
    log: list[str] = []
    pubs: dict[str, Any] = {}
    sender = ZenohSender(ThreadRegistry(), "zenoh-events", pub_of=pubs.get)
    sender.start()
    try:
        for i in range(3):
            sender.put_event("emcy", f"{i}".encode(), i)
        wait_until_sync(lambda: len(sender.backlog) == 3, 5, "3 events kept")
        pubs["emcy"] = Pub("emcy", log)  # the session's publishers are declared
        sender.put_event("emcy", b"3", 3)  # a newer one may come first: it goes out after
        sender.resend()
        wait_until_sync(lambda: len(log) == 4, 5, "4 events out")
    finally:
        sender.stop()
    assert sender.sent == 4 and not sender.backlog


def test_an_event_of_a_key_this_gateway_no_longer_publishes_never_holds_the_others_back() -> None:
    """Kept while no session was open, an event of a node whose network the pair's other member
    masters by the time the session opens (``WITHHELD``) is counted, not published, and the
    events behind it go out."""
    log: list[str] = []
    pubs: dict[str, Any] = {}
    sender = ZenohSender(ThreadRegistry(), "zenoh-events", pub_of=pubs.get)
    sender.start()
    try:
        for key in ("rotary", "wire", "rotary", "wire"):
            sender.put_event(key, b"{}", 1)
        wait_until_sync(lambda: len(sender.backlog) == 4, 5, "4 events kept")
        pubs["wire"], pubs["rotary"] = Pub("wire", log), WITHHELD  # line2 stood by meanwhile
        sender.resend()
        sender.put_event("wire", b"{}", 2)
        wait_until_sync(lambda: len(log) == 3, 5, "wire's 3 events out")
    finally:
        sender.stop()
    assert log == ["wire"] * 3 and sender.withheld == 2 and not sender.backlog


async def test_values_are_put_on_the_publish_thread_never_on_the_can_reader() -> None:
    gw = gateway_of(make_config([WIRE], simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp"}}}))
    await gw.start()
    try:
        await wait_until(lambda: gw.status()["ready"], 8, "ready")
        assert gw.zenoh is not None
        threads: list[str] = []
        done = threading.Event()

        class Recording:
            def __init__(self, pub: Any) -> None:
                self.pub = pub

            def put(self, payload: Any, **kw: Any) -> None:
                name = threading.current_thread().name
                threads.append(name)
                if threads.count("zenoh-publish") >= 20:
                    done.set()
                self.pub.put(payload, **kw)

        for sp in gw.zenoh.pubs.values():
            sp.pub = Recording(sp.pub)
        await wait_until(done.is_set, 8, "20 value samples")
        # the loop puts only what no frame announces (housekeeping: quality by age, held-back
        # samples); the reader never puts
        assert "can-reader" not in threads
        assert set(threads) <= {"zenoh-publish", "MainThread"}, threads
    finally:
        await gw.stop()



async def test_an_event_put_that_blocks_does_not_hold_the_values_back() -> None:
    gw = gateway_of(make_config([WIRE], simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp"}}}))
    await gw.start()
    release = threading.Event()
    try:
        await wait_until(lambda: gw.status()["ready"], 8, "ready")
        assert gw.zenoh is not None
        blocked = threading.Event()

        class Congested:  # a BLOCK put waiting for a congested link
            def put(self, payload: bytes, timestamp: Any = None) -> None:
                blocked.set()
                release.wait(30)

        events = gw.zenoh._events
        known = events.pub_of
        events.pub_of = lambda key: Congested() if key == "congested" else known(key)
        events.put_event("congested", b"{}", 1)
        await wait_until(blocked.is_set, 8, "the event put blocked")
        puts: list[str] = []
        enough = threading.Event()

        class Counting:
            def __init__(self, pub: Any) -> None:
                self.pub = pub

            def put(self, payload: Any, **kw: Any) -> None:
                puts.append(threading.current_thread().name)
                if len(puts) >= 10:
                    enough.set()
                self.pub.put(payload, **kw)

        for sp in gw.zenoh.pubs.values():
            sp.pub = Counting(sp.pub)
        await wait_until(enough.is_set, 8, "10 value samples while the event put blocks")
        assert blocked.is_set() and not release.is_set()
        assert "zenoh-publish" in puts
    finally:
        release.set()
        await gw.stop()
