"""The scan's python-can bus on the gateway's own connection (``bus.tap_bus.TapBus``) and the
driver's frame taps: frames the reader takes reach every tap in order, a tap that fails never
stops the reader, and what a tool sends goes out through the driver's sender queue."""

from __future__ import annotations

import can
import pytest

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.tap_bus import TapBus
from canopen_gateway.image import ProcessImage


def msg(cob_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


class ScriptedBus:
    """A backend that hands over its frames, then ends the reader's loop."""

    def __init__(self, d: BusDriver, frames: list[can.Message]) -> None:
        self.d, self.frames = d, list(frames)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self.frames:
            return self.frames.pop(0)
        self.d._running.clear()
        return None

    def shutdown(self) -> None:
        pass


def driver() -> BusDriver:
    d = BusDriver({"interface": "virtual", "channel": "unused"}, ProcessImage())
    d.state = "ok"
    return d


def run_reader(d: BusDriver, frames: list[can.Message]) -> None:
    d.bus = ScriptedBus(d, frames)  # type: ignore[assignment]
    d._running.set()
    d._run()


def test_a_tap_that_fails_does_not_stop_the_reader_or_the_other_taps() -> None:
    d = driver()
    handled: list[int] = []
    tapped: list[int] = []
    d.handlers[0x181] = lambda m: handled.append(m.arbitration_id)

    def broken(m: can.Message) -> None:
        raise RuntimeError("a tap's bug")

    d.add_tap(broken)
    d.add_tap(lambda m: tapped.append(m.arbitration_id))
    run_reader(d, [msg(0x181, bytes(8)), msg(0x701, b"\x05")])
    assert handled == [0x181]  # the frame was decoded all the same
    assert tapped == [0x181, 0x701]
    assert d.rx_counters["frames_in"] == 2


def test_a_tap_bus_receives_what_the_reader_takes_while_it_is_open() -> None:
    d = driver()
    bus = TapBus(d)
    run_reader(d, [msg(0x701, b"\x05"), msg(0x587, b"\x43\x00\x10\x00\x91\x01\x0a\x00")])
    first, second = bus.recv(0), bus.recv(0)
    assert first is not None and first.arbitration_id == 0x701
    assert second is not None and bytes(second.data[:4]) == b"\x43\x00\x10\x00"
    assert bus.recv(0) is None
    bus.shutdown()
    assert d.frame_taps == ()  # closed: the reader no longer hands frames to it
    run_reader(d, [msg(0x701, b"\x05")])
    assert bus._queue.empty()


def test_a_tap_bus_that_falls_behind_drops_the_newest_frames_and_counts_them() -> None:
    d = driver()
    bus = TapBus(d, queue_max=2)
    run_reader(d, [msg(0x701, b"\x05")] * 5)  # never blocks the reader
    assert bus.lost == 3
    assert bus.recv(0) is not None and bus.recv(0) is not None and bus.recv(0) is None
    bus.shutdown()


def test_a_tap_bus_sends_through_the_drivers_sender_and_refuses_29_bit_ids() -> None:
    d = driver()
    d.bus = ScriptedBus(d, [])  # type: ignore[assignment]
    bus = TapBus(d)
    bus.send(can.Message(arbitration_id=0x607, data=b"\x40\x00\x10\x00\x00\x00\x00\x00",
                         is_extended_id=False))  # fmt: skip
    queued = d._tx.get_nowait()
    assert queued.arbitration_id == 0x607 and bytes(queued.data) == b"\x40\x00\x10\x00" + bytes(4)
    with pytest.raises(can.CanOperationError):
        bus.send(can.Message(arbitration_id=0x18FF0000, data=b"", is_extended_id=True))
    d.state = "down"  # while the bus is down a send fails at once
    with pytest.raises(can.CanOperationError):
        bus.send(msg(0x607, bytes(8)))
    bus.shutdown()
