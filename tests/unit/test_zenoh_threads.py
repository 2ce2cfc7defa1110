"""The Zenoh bridge's value batches, threads and retries, without a network: a batch never
loses a mark, an exception in publishing is logged and publishing goes on, a thread that dies
turns the gateway not-ready (and carries its name in the kernel, for top -H), client-mode
attempts start on the documented schedule, and two flushes at once never publish an older
value after a newer one."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import pytest
import zenoh

from canopen_gateway.image import SignalView
from canopen_gateway.runtime import threads
from canopen_gateway.zenoh_bridge.bridge import _ValueBatch
from canopen_gateway.zenoh_bridge.session import REOPEN_SCHEDULE_S
from tests.helpers import gateway_of, make_config, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


class Sp:
    def __init__(self, key: str) -> None:
        self.key = key


def test_a_mark_made_while_a_batch_is_published_goes_out_in_the_next_batch() -> None:
    """The mark arrives exactly while the sender publishes (from inside the offer): it must
    not land in the batch already taken, nor be lost."""
    a, b = Sp("a"), Sp("b")
    offered: list[str] = []
    sender: _ValueBatch

    def offer(node: Any, sp: Any, now: float) -> None:
        offered.append(sp.key)
        if sp is a and offered.count("a") == 1:
            sender.mark(None, b)  # the CAN reader marks b meanwhile  # type: ignore[arg-type]

    sender = _ValueBatch(offer)  # type: ignore[arg-type]
    sender.mark(None, a)  # type: ignore[arg-type]
    sender.flush()
    assert offered == ["a"]
    sender.flush()
    assert offered == ["a", "b"]
    sender.flush()
    assert offered == ["a", "b"]


def test_marks_are_published_at_the_end_of_the_batch_once_per_signal() -> None:
    offered: list[str] = []
    batch = _ValueBatch(lambda node, sp, now: offered.append(sp.key))  # type: ignore[arg-type]
    batch.flush()
    assert offered == []  # nothing marked: nothing published
    a, b = Sp("a"), Sp("b")
    for sp in (a, b, a, a):  # a burst: a's three frames coalesce into one sample
        batch.mark(None, sp)  # type: ignore[arg-type]
    assert offered == []  # the reader's burst is not over yet
    batch.flush()
    assert offered == ["a", "b"]
    batch.flush()
    assert offered == ["a", "b"]


def test_marks_from_a_reader_flushed_concurrently_by_another_writer_are_all_published() -> None:
    """The reader marks and flushes its bursts while the event loop flushes its own batches
    (values read by SDO) at the same time: every signal's last value goes out."""
    sps = [Sp(f"s{i}") for i in range(50)]
    latest: dict[str, int] = {}
    published: dict[str, int] = {}
    done = threading.Event()

    def offer(node: Any, sp: Any, now: float) -> None:
        published[sp.key] = latest[sp.key]

    batch = _ValueBatch(offer)  # type: ignore[arg-type]

    def reader() -> None:
        for round_ in range(200):
            for sp in sps:
                latest[sp.key] = round_  # the image is written, then the signal marked
                batch.mark(None, sp)  # type: ignore[arg-type]
            batch.flush()  # end of the reader's burst
        done.set()

    def other_writer() -> None:
        while not done.is_set():
            batch.flush()

    threads = [threading.Thread(target=reader), threading.Thread(target=other_writer)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert done.is_set()
    assert published == latest  # the last value of every signal went out
    assert batch.pending == {}


def test_an_exception_while_publishing_is_logged_and_publishing_goes_on(caplog: Any) -> None:
    bad, good = Sp("bad"), Sp("good")
    offered: list[str] = []

    def offer(node: Any, sp: Any, now: float) -> None:
        if sp is bad:
            raise ValueError("cannot encode")
        offered.append(sp.key)

    sender = _ValueBatch(offer)  # type: ignore[arg-type]
    sender.mark(None, bad)  # type: ignore[arg-type]
    sender.flush()
    sender.mark(None, good)  # type: ignore[arg-type]
    sender.flush()
    assert offered == ["good"] and sender.errors == 1
    assert any("publishing bad failed" in r.getMessage() for r in caplog.records)


async def test_a_dead_zenoh_thread_turns_the_gateway_not_ready() -> None:
    gw = gateway_of(make_config([WIRE], simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp"}}}))
    await gw.start()
    try:
        await wait_until(lambda: gw.status()["ready"], 8, "ready")
        assert gw.zenoh is not None

        class Dying:
            def put(self, payload: bytes, timestamp: Any = None) -> None:
                raise SystemExit("simulated death")  # not an Exception: escapes the loop

        events = gw.zenoh._events
        events.pub_of = lambda key: Dying()
        events.put_event("dying", b"{}", 1)
        await wait_until(lambda: not gw.status()["ready"], 8, "not ready")
        st = gw.status()
        assert "zenoh-events" in st["threads"]["failed"]
        assert "simulated death" in st["threads"]["failed"]["zenoh-events"]
    finally:
        await gw.stop()


async def test_client_mode_attempts_start_on_the_documented_schedule() -> None:
    """Docs: retried in the background after 0.5 s, 1 s, 2 s, then every 5 s; each attempt
    takes the connect timeout (1 s) itself, which must not add up."""
    gw = gateway_of(make_config([WIRE], zenoh={"mode": "client", "connect": ["tcp/127.0.0.1:9"]}))
    bridge = gw.zenoh
    assert bridge is not None
    now = [0.0]
    starts: list[float] = []

    async def sleep(s: float) -> None:
        assert s >= 0
        now[0] += s

    async def try_open() -> Any:
        starts.append(now[0])
        now[0] += 1.0  # the connect timeout
        if len(starts) == 6:
            link.session = object()  # type: ignore[assignment]  # stop here
        raise zenoh.ZError("no router")

    link = bridge.link
    link.clock = lambda: now[0]
    link.sleep = sleep
    link.try_open = try_open  # type: ignore[method-assign]
    link.last_attempt_s = 0.0  # the first attempt, at start, began at 0 and took 1 s
    now[0] = 1.0
    await link.reopen()
    assert REOPEN_SCHEDULE_S == (0.5, 1.0, 2.0, 5.0)
    # an attempt longer than the period (1 s > 0.5 s) is followed by the next one at once;
    # from then on attempts start 1 s, 2 s, then 5 s apart, whatever they last
    assert starts == pytest.approx([1.0, 2.0, 4.0, 9.0, 14.0, 19.0])
    link.session = None


class WatchedLock:
    """A signal's lock that says when a given thread starts waiting for it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.watched: threading.Thread | None = None
        self.settled = threading.Event()  # the watched thread waits for the lock, or is done

    def __enter__(self) -> WatchedLock:
        if threading.current_thread() is self.watched:
            self.settled.set()
        self._lock.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self._lock.release()


async def test_two_flushes_at_once_never_publish_an_older_value_after_a_newer_one() -> None:
    """The event loop flushes a signal (A) and the reader's burst flushes it too (B). A reads
    the value (seq 1); exactly then a new frame lands (seq 2) and B publishes. A sample of
    seq 1 after the one of seq 2 would stay the latest under report by exception."""
    gw = gateway_of(make_config([WIRE], simulate={"nodes": []}, modbus={"enabled": False}))
    await gw.start()
    try:
        bridge = gw.zenoh
        assert bridge is not None
        await wait_until(lambda: bridge.session is not None, 5, "zenoh session")
        image, node = gw.image, gw.image.nodes["wire"]
        tpdo = next(c for c in gw.master.nodes["wire"].tpdos if "position" in c.names)
        sp = bridge.pubs[("wire", "position")]
        published: list[int] = []
        real_pub = sp.pub

        class Recording:
            def put(self, payload: str, timestamp: Any = None) -> None:
                published.append(json.loads(payload)["seq"])
                real_pub.put(payload, timestamp=timestamp)

        lock = WatchedLock()
        sp.pub, sp.lock = Recording(), lock  # type: ignore[assignment]
        frame = {1: tuple(1 if n == "position" else 0 for n in tpdo.names),
                 2: tuple(2 if n == "position" else 0 for n in tpdo.names)}  # fmt: skip

        def flush_b() -> None:
            try:
                bridge.offer(node, sp, time.monotonic())
            finally:
                lock.settled.set()

        class ViewThatLetsBIn(SignalView):
            fired = False

            def __getitem__(self, name: str) -> Any:
                sv = super().__getitem__(name)  # A has read seq 1 ...
                if name == "position" and not ViewThatLetsBIn.fired:
                    ViewThatLetsBIn.fired = True
                    image.update(node, tpdo.names, frame[2], time.time())  # ... a frame lands
                    lock.watched = threading.Thread(target=flush_b)
                    lock.watched.start()
                    assert lock.settled.wait(5)  # B published, or waits for the lock
                return sv

        image.update(node, tpdo.names, frame[1], time.time())
        node.signals = ViewThatLetsBIn(node.records, node.where)
        bridge.offer(node, sp, time.monotonic())  # A
        assert lock.watched is not None
        lock.watched.join(5)
        assert published == sorted(published) and published[-1] == 2, published
        assert sp.last_seq == 2
    finally:
        await gw.stop()


def test_a_supervised_thread_carries_its_name_in_the_kernel() -> None:
    """``top -H`` and /proc/PID/task/TID/comm show the gateway's thread names."""
    import os
    import sys

    import pytest

    if not sys.platform.startswith("linux"):
        pytest.skip("thread names in /proc are Linux's")
    seen: list[str] = []
    done = threading.Event()

    def target() -> None:
        with open(f"/proc/{os.getpid()}/task/{threading.get_native_id()}/comm") as f:
            seen.append(f.read().strip())
        done.set()

    threads.ThreadRegistry().start("zenoh-publish", target)
    assert done.wait(10)
    assert seen == ["zenoh-publish"]
