"""The web console's live hub: one coalesced hand-off from the reader thread, at most 10 updates
a second per client, and a slow client that never holds anything up."""

from __future__ import annotations

import asyncio
import threading

from canopen_gateway.http.messages import StreamOut
from canopen_gateway.image import NodeImage, ProcessImage
from canopen_gateway.web.live import (
    MIN_SEND_INTERVAL_S,
    RETRY_MS,
    LiveHub,
    Subscriber,
    sse,
    stream_sse,
)


def _image() -> tuple[ProcessImage, NodeImage]:
    image = ProcessImage()
    node = NodeImage("wire", 1, "sgh10", ["position", "velocity"])
    image.add_node(node)
    return image, node


class FakeTransport:
    def __init__(self, buffered: int = 0):
        self.buffered = buffered
        self.closing = False

    def get_write_buffer_size(self) -> int:
        return self.buffered

    def is_closing(self) -> bool:
        return self.closing


class FakeWriter:
    """Records what is written and the loop time of each write."""

    def __init__(self, transport: FakeTransport):
        self.transport = transport
        self.writes: list[tuple[float, bytes]] = []
        self.written = asyncio.Event()

    def write(self, data: bytes) -> None:
        self.writes.append((asyncio.get_running_loop().time(), data))
        self.written.set()


def _render(sub: Subscriber, full: bool) -> list[tuple[str, object]]:
    values, sub.dirty_values = sub.dirty_values, set()
    return [("values", sorted(values))] if values or full else []


async def test_frames_from_the_reader_thread_reach_the_loop_in_few_coalesced_hand_offs() -> None:
    image, node = _image()
    hub = LiveHub(image)
    hub.attach(asyncio.get_running_loop())
    sub = hub.subscribe("wire")
    frames = 5000

    def reader() -> None:
        for i in range(frames):
            image.update(node, ("position", "velocity") if i % 2 else ("position",), (i, 1), 0.0)

    thread = threading.Thread(target=reader)
    thread.start()
    await asyncio.to_thread(thread.join)
    # the first hand-off may have run between the first two frames: wait for the batches that
    # follow it (each sets the page's wake event) until both signals are in
    while sub.dirty_values != {"position", "velocity"}:
        await asyncio.wait_for(sub.wake.wait(), 5)
        sub.wake.clear()
    # one call_soon_threadsafe per armed period, never one per frame
    assert 1 <= hub.handoffs < frames / 10
    hub.detach()


async def test_nobody_watching_a_node_costs_no_hand_off() -> None:
    image, node = _image()
    hub = LiveHub(image)
    hub.attach(asyncio.get_running_loop())
    index_page = hub.subscribe(None)  # overview: health only
    for i in range(100):
        image.update(node, ("position",), (i,), 0.0)
    assert hub.handoffs == 0
    assert index_page.dirty_values == set()
    hub.unsubscribe(index_page)
    hub.detach()


async def test_health_changes_wake_the_pages_that_show_that_node() -> None:
    image, node = _image()
    other = NodeImage("magnet", 2, "msk5000", ["position"])
    image.add_node(other)
    hub = LiveHub(image)
    hub.attach(asyncio.get_running_loop())
    index_page, wire_page, magnet_page = hub.subscribe(None), hub.subscribe("wire"), hub.subscribe("magnet")
    image.health_changed(node, "state")
    assert index_page.dirty_health == {"wire"} and index_page.wake.is_set()
    assert wire_page.dirty_health == {"wire"}
    assert magnet_page.dirty_health == set() and not magnet_page.wake.is_set()
    hub.detach()


async def test_a_client_gets_at_most_ten_updates_a_second_with_the_latest_values() -> None:
    image, node = _image()
    hub = LiveHub(image)
    hub.attach(asyncio.get_running_loop())
    sub = hub.subscribe("wire")
    writer = FakeWriter(FakeTransport())
    gone = asyncio.get_running_loop().create_future()  # not done: the client stays
    pump = asyncio.create_task(hub.pump(sub, _render, StreamOut(writer, gone)))

    async def producer() -> None:
        i = 0
        while True:
            image.update(node, ("position",), (i,), 0.0)
            i += 1
            await asyncio.sleep(0.002)

    feeding = asyncio.create_task(producer())
    try:
        while len(writer.writes) < 8:  # retry line + full refresh + updates
            writer.written.clear()
            await asyncio.wait_for(writer.written.wait(), 5)
    finally:
        feeding.cancel()
        gone.set_result(None)  # the browser goes away
        await asyncio.wait_for(pump, 5)
    updates = [t for t, data in writer.writes if data.startswith(b"event:")]
    gaps = [b - a for a, b in zip(updates, updates[1:], strict=False)]
    assert gaps and min(gaps) >= MIN_SEND_INTERVAL_S - 1e-3
    assert sub not in hub.subscribers  # unsubscribed when the client left
    hub.detach()


async def test_a_client_that_does_not_read_is_skipped_then_dropped_and_stays_bounded() -> None:
    image, node = _image()
    hub = LiveHub(image)
    hub.attach(asyncio.get_running_loop())
    sub = hub.subscribe("wire")
    transport = FakeTransport(buffered=10**9)  # the socket never drains
    writer = FakeWriter(transport)
    pump = asyncio.create_task(
        hub.pump(sub, _render, StreamOut(writer, asyncio.get_running_loop().create_future()), slow_limit_s=0.3)
    )
    for i in range(10_000):
        image.update(node, ("position", "velocity"), (i, i), 0.0)
        if i % 1000 == 0:
            await asyncio.sleep(0)
    await asyncio.wait_for(pump, 5)  # dropped after the limit, without anyone reading
    assert [d for _, d in writer.writes if d.startswith(b"event:")] == []
    assert sub.skipped >= 1
    assert sub.dirty_values <= {"position", "velocity"}  # a set of names, not a queue
    assert sub not in hub.subscribers
    hub.detach()


def test_server_sent_event_format() -> None:
    assert sse("values", {"a": 1}) == b'event: values\ndata: {"a":1}\n\n'


async def test_the_one_sse_pump_writes_retry_and_first_then_a_turn_per_wake_until_the_browser_goes() -> None:
    writer = FakeWriter(FakeTransport())
    gone = asyncio.get_running_loop().create_future()
    wake = asyncio.Event()
    turns: list[float] = []

    def turn(now: float) -> bytes:
        turns.append(now)
        return b"event: x\ndata: 1\n\n"

    pump = asyncio.create_task(
        stream_sse(StreamOut(writer, gone), wake, turn, lambda: float("inf"), interval_s=0.0,
                   who="test page", first=b"event: hello\ndata: {}\n\n")  # fmt: skip
    )
    await asyncio.wait_for(writer.written.wait(), 5)
    assert writer.writes[0][1] == f"retry: {RETRY_MS}\n\n".encode() + b"event: hello\ndata: {}\n\n"
    assert turns == []  # nothing due, nothing woke it
    writer.written.clear()
    wake.set()
    await asyncio.wait_for(writer.written.wait(), 5)
    assert len(turns) == 1 and writer.writes[1][1] == b"event: x\ndata: 1\n\n"
    assert not wake.is_set()  # the turn took what woke it
    gone.set_result(None)  # the browser goes away
    await asyncio.wait_for(pump, 5)
    assert len(turns) == 1


async def test_the_one_sse_pump_skips_a_client_that_does_not_read_then_drops_it() -> None:
    writer = FakeWriter(FakeTransport(buffered=10**9))  # the socket never drains
    wake = asyncio.Event()
    wake.set()
    skipped: list[int] = []

    def turn(now: float) -> bytes:
        raise AssertionError("a turn while the socket does not drain")

    await asyncio.wait_for(
        stream_sse(StreamOut(writer, asyncio.get_running_loop().create_future()), wake, turn, lambda: float("inf"),
                   interval_s=0.01, who="test page", on_skip=lambda: skipped.append(1),
                   slow_limit_s=0.05),  # fmt: skip
        5,
    )
    assert len(skipped) >= 2 and wake.is_set()  # what woke it is still there, never written
    assert len(writer.writes) == 1  # the retry line only
