"""The Zenoh bridge's own threads and retries, without a network: the value hand-off never
loses a mark, an exception in publishing is logged and the thread goes on, a thread that dies
turns the gateway not-ready, and client-mode attempts start on the documented schedule."""

from __future__ import annotations

import threading
from typing import Any

import pytest
import zenoh

from gateway.app import Gateway
from gateway.threads import ThreadRegistry
from gateway.zenoh_bridge.bridge import REOPEN_SCHEDULE_S, _ValueSender
from tests.helpers import make_config, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


class Sp:
    def __init__(self, key: str) -> None:
        self.key = key


def test_a_mark_made_while_a_batch_is_published_goes_out_in_the_next_batch() -> None:
    """The mark arrives exactly while the sender publishes (from inside the offer): it must
    not land in the batch already taken, nor be lost."""
    a, b = Sp("a"), Sp("b")
    offered: list[str] = []
    sender: _ValueSender

    def offer(node: Any, sp: Any, now: float) -> None:
        offered.append(sp.key)
        if sp is a and offered.count("a") == 1:
            sender.mark(None, b)  # the CAN reader marks b meanwhile  # type: ignore[arg-type]

    sender = _ValueSender(offer, ThreadRegistry())  # type: ignore[arg-type]
    sender.mark(None, a)  # type: ignore[arg-type]
    sender.publish_pending()
    assert offered == ["a"]
    sender.publish_pending()
    assert offered == ["a", "b"]
    sender.publish_pending()
    assert offered == ["a", "b"]


def test_marks_wake_the_sender_once_per_burst_not_once_per_value() -> None:
    sender = _ValueSender(lambda node, sp, now: None, ThreadRegistry())  # type: ignore[arg-type]
    sender.flush()
    assert not sender.wake.is_set()  # nothing marked: nothing to wake for
    for key in ("a", "b", "c"):
        sender.mark(None, Sp(key))  # type: ignore[arg-type]
        assert not sender.wake.is_set()  # the reader's burst is not over yet
    sender.flush()
    assert sender.wake.is_set()
    assert [sp.key for _, sp in sender.take()] == ["a", "b", "c"]


def test_marks_from_a_concurrent_reader_are_all_published() -> None:
    sps = [Sp(f"s{i}") for i in range(50)]
    latest: dict[str, int] = {}
    published: dict[str, int] = {}
    done = threading.Event()

    def offer(node: Any, sp: Any, now: float) -> None:
        published[sp.key] = latest[sp.key]

    sender = _ValueSender(offer, ThreadRegistry())  # type: ignore[arg-type]
    sender.start()
    try:

        def reader() -> None:
            for round_ in range(200):
                for sp in sps:
                    latest[sp.key] = round_  # the image is written, then the signal marked
                    sender.mark(None, sp)  # type: ignore[arg-type]
                sender.flush()  # end of the reader's burst
            done.set()

        t = threading.Thread(target=reader)
        t.start()
        t.join(30)
        assert done.is_set()
        deadline = threading.Event()
        for _ in range(500):  # bounded: the sender wakes on each flush
            if published == latest:
                break
            deadline.wait(0.01)
        assert published == latest  # the last value of every signal went out
    finally:
        sender.stop()


def test_an_exception_while_publishing_is_logged_and_the_thread_goes_on(caplog: Any) -> None:
    bad, good = Sp("bad"), Sp("good")
    offered: list[str] = []

    def offer(node: Any, sp: Any, now: float) -> None:
        if sp is bad:
            raise ValueError("cannot encode")
        offered.append(sp.key)

    sender = _ValueSender(offer, ThreadRegistry())  # type: ignore[arg-type]
    sender.mark(None, bad)  # type: ignore[arg-type]
    sender.publish_pending()
    sender.mark(None, good)  # type: ignore[arg-type]
    sender.publish_pending()
    assert offered == ["good"] and sender.errors == 1
    assert any("publishing bad failed" in r.getMessage() for r in caplog.records)


async def test_a_dead_zenoh_thread_turns_the_gateway_not_ready() -> None:
    gw = Gateway(make_config([WIRE], simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp"}}}))
    await gw.start()
    try:
        await wait_until(lambda: gw.status()["ready"], 8, "ready")
        assert gw.zenoh is not None

        def die(node: Any, sp: Any, now: float) -> None:
            raise SystemExit("simulated death")  # not an Exception: escapes the thread's loop

        gw.zenoh._values.offer = die
        await wait_until(lambda: not gw.status()["ready"], 8, "not ready")
        st = gw.status()
        assert "zenoh-values" in st["threads"]["failed"]
        assert "simulated death" in st["threads"]["failed"]["zenoh-values"]
    finally:
        await gw.stop()


async def test_client_mode_attempts_start_on_the_documented_schedule() -> None:
    """Docs: retried in the background after 0.5 s, 1 s, 2 s, then every 5 s; each attempt
    takes the connect timeout (1 s) itself, which must not add up."""
    gw = Gateway(make_config([WIRE], zenoh={"mode": "client", "connect": ["tcp/127.0.0.1:9"]}))
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
            bridge.session = object()  # type: ignore[assignment]  # stop here
        raise zenoh.ZError("no router")

    bridge._clock = lambda: now[0]
    bridge._sleep = sleep
    bridge._try_open = try_open  # type: ignore[method-assign]
    bridge._last_attempt_s = 0.0  # the first attempt, at start, began at 0 and took 1 s
    now[0] = 1.0
    await bridge._reopen()
    assert REOPEN_SCHEDULE_S == (0.5, 1.0, 2.0, 5.0)
    # an attempt longer than the period (1 s > 0.5 s) is followed by the next one at once;
    # from then on attempts start 1 s, 2 s, then 5 s apart, whatever they last
    assert starts == pytest.approx([1.0, 2.0, 4.0, 9.0, 14.0, 19.0])
    bridge.session = None
