"""The reader takes frames in bursts: the burst listeners run once after every frame already
received has been handled, not once per frame, and every ``burst_max_frames`` frames while
frames keep coming (python-can virtual bus, real reader thread)."""

from __future__ import annotations

import threading
import uuid

import can

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.image import ProcessImage
from canopen_gateway.runtime.threads import ThreadRegistry
from canopen_gateway.zenoh_bridge.sender import ZenohSender

WAIT_S = 5.0


def test_burst_listeners_run_once_per_burst_after_every_buffered_frame() -> None:
    channel = f"burst-{uuid.uuid4().hex}"
    # a burst shorter than ``burst_max_frames``
    d = BusDriver({"interface": "virtual", "channel": channel}, ProcessImage(), burst_max_frames=64)
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


def test_while_frames_keep_coming_the_listeners_run_every_burst_max_frames() -> None:
    """A backlog the reader never gets to the end of (sustained overload): what the frames
    brought is handed over every ``burst_max_frames`` frames, not only when the bus pauses."""
    channel = f"burst-{uuid.uuid4().hex}"
    d = BusDriver({"interface": "virtual", "channel": channel}, ProcessImage(), burst_max_frames=16)
    handled: list[int] = []
    calls: list[int] = []
    entered, go, done = threading.Event(), threading.Event(), threading.Event()

    def handle(msg: can.Message) -> None:
        if not handled:
            entered.set()
            assert go.wait(WAIT_S)  # hold the reader while the backlog is queued
        handled.append(msg.data[0])

    def on_burst() -> None:
        calls.append(len(handled))
        if len(handled) == 100:
            done.set()

    d.handlers[0x181] = handle
    d.burst_listeners.append(on_burst)
    d.open()
    device = can.Bus(interface="virtual", channel=channel)
    try:
        device.send(can.Message(arbitration_id=0x181, data=[0], is_extended_id=False))
        assert entered.wait(WAIT_S)
        for i in range(1, 100):
            device.send(can.Message(arbitration_id=0x181, data=[i], is_extended_id=False))
        go.set()
        assert done.wait(WAIT_S)
        assert calls == [16, 32, 48, 64, 80, 96, 100]  # the last one: nothing left buffered
        assert handled == list(range(100))
        assert d.image.counters["bursts"] == 1  # one wake-up of the reader for the backlog
    finally:
        device.shutdown()
        d.close()


def test_a_backlog_the_reader_never_gets_through_still_reaches_zenoh() -> None:
    """Sustained overload (the reader behind, the bus never pausing): the Zenoh publisher,
    woken through the burst listeners, flushes while frames are still being handled. The
    reader's handler for frame 100 waits for a flush: before, the only flush came after the
    last frame."""
    channel = f"burst-{uuid.uuid4().hex}"
    d = BusDriver({"interface": "virtual", "channel": channel}, ProcessImage())
    handled: list[int] = []
    flushed_at: list[int] = []
    flushed = threading.Event()
    entered, go, all_handled = threading.Event(), threading.Event(), threading.Event()

    def flush() -> None:
        flushed_at.append(len(handled))
        flushed.set()

    sender = ZenohSender(ThreadRegistry(), "zenoh-publish", flush, batch_s=0.001)

    def handle(msg: can.Message) -> None:
        if not handled:
            entered.set()
            assert go.wait(WAIT_S)  # hold the reader while the backlog is queued
        if len(handled) == 100:
            assert flushed.wait(WAIT_S), "no flush while the frames keep coming"
        handled.append(msg.data[1])
        if len(handled) == 200:
            all_handled.set()

    d.handlers[0x181] = handle
    d.burst_listeners.append(sender.wake_values)
    sender.start()
    d.open()
    device = can.Bus(interface="virtual", channel=channel)
    try:
        device.send(can.Message(arbitration_id=0x181, data=[0, 0], is_extended_id=False))
        assert entered.wait(WAIT_S)
        for i in range(1, 200):
            device.send(can.Message(arbitration_id=0x181, data=[0, i % 256], is_extended_id=False))
        go.set()
        assert all_handled.wait(WAIT_S)
        assert flushed_at and flushed_at[0] < 200
        assert d.image.counters["decode_errors"] == 0
    finally:
        device.shutdown()
        d.close()
        sender.stop()
