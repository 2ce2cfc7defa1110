"""The reader takes frames in bursts: the burst listeners run once after every frame already
received has been handled, not once per frame (python-can virtual bus, real reader thread)."""

from __future__ import annotations

import threading
import uuid

import can

from gateway.bus.driver import BusDriver
from gateway.image import ProcessImage
from tests.helpers import wait_until_sync

WAIT_S = 5.0


def test_burst_listeners_run_once_per_burst_after_every_buffered_frame() -> None:
    channel = f"burst-{uuid.uuid4().hex}"
    d = BusDriver({"interface": "virtual", "channel": channel}, ProcessImage())
    handled: list[int] = []
    bursts: list[int] = []
    entered, go, burst_seen = threading.Event(), threading.Event(), threading.Event()

    def handle(msg: can.Message) -> None:
        if not handled:
            entered.set()
            assert go.wait(WAIT_S)  # hold the reader while the rest of the burst is queued
        handled.append(msg.data[0])

    def failing() -> None:
        raise RuntimeError("a broken listener")

    def on_burst() -> None:
        bursts.append(len(handled))
        burst_seen.set()

    d.handlers[0x181] = handle
    d.burst_listeners += [failing, on_burst]
    d.open()
    device = can.Bus(interface="virtual", channel=channel)
    try:
        device.send(can.Message(arbitration_id=0x181, data=[0], is_extended_id=False))
        assert entered.wait(WAIT_S)
        for i in range(1, 20):
            device.send(can.Message(arbitration_id=0x181, data=[i], is_extended_id=False))
        go.set()
        assert burst_seen.wait(WAIT_S)
        assert bursts == [20]  # one call, after all 20 frames
        assert handled == list(range(20))
        assert d.idle  # nothing left buffered: the bus clock is the monotonic clock

        burst_seen.clear()
        device.send(can.Message(arbitration_id=0x181, data=[20], is_extended_id=False))
        assert burst_seen.wait(WAIT_S)  # a failing listener does not stop the others
        assert bursts == [20, 21]
        assert d.threads.failures() == {}
        # counted: two bursts (wake-ups) for 21 frames (canopen_gateway_can_bursts_total)
        assert d.image.counters["bursts"] == 2 and d.image.counters["frames_in"] == 21
    finally:
        device.shutdown()
        d.close()


def test_with_a_gap_the_ends_of_bursts_within_it_are_taken_together() -> None:
    """``burst_gap_s`` (``zenoh.batch_ms``): the burst listeners run at most once per gap of
    the driver's clock (a fake one here, standing still until the test moves it): the frames of
    the bursts within the gap are handed over in one call, none is left behind."""
    channel = f"burst-{uuid.uuid4().hex}"
    now = [100.0]
    d = BusDriver({"interface": "virtual", "channel": channel}, ProcessImage(), mono=lambda: now[0])
    d.burst_gap_s = 1.0
    handled: list[int] = []
    calls: list[int] = []
    called = threading.Event()

    def on_burst() -> None:
        calls.append(len(handled))
        called.set()

    d.handlers[0x181] = lambda msg: handled.append(msg.data[0])
    d.burst_listeners.append(on_burst)
    d.open()
    device = can.Bus(interface="virtual", channel=channel)
    bursts = d.image.counters
    try:
        device.send(can.Message(arbitration_id=0x181, data=[0], is_extended_id=False))
        assert called.wait(WAIT_S)  # the first burst: no gap to wait for
        assert calls == [1]
        called.clear()
        for i in (1, 2):  # two more bursts, each its own wake-up, within the gap
            device.send(can.Message(arbitration_id=0x181, data=[i], is_extended_id=False))
            wait_until_sync(lambda i=i: bursts["bursts"] == i + 1, WAIT_S, f"burst {i + 1} taken")
        assert handled == [0, 1, 2]
        assert calls == [1]  # the clock stands still: the gap is not over
        now[0] += 1.0
        assert called.wait(WAIT_S)
        assert calls == [1, 3]  # one call for both bursts, after every frame
    finally:
        device.shutdown()
        d.close()
