"""Supervision judges timeouts by the frames the reader has processed: a backlog in the receive
queue must not turn a healthy node into a lost one. Fake monotonic and wall clocks."""

from __future__ import annotations

import can

from canopen_gateway.bus.driver import FRAME_AGE_MAX_S, BusDriver
from canopen_gateway.image import ProcessImage


class Clocks:
    def __init__(self) -> None:
        self.mono = 1000.0
        self.wall = 1_700_000_000.0


def driver(c: Clocks) -> BusDriver:
    return BusDriver(
        {"interface": "virtual", "channel": "unused"},
        ProcessImage(),
        mono=lambda: c.mono,
        wall=lambda: c.wall,
    )


def test_bus_clock_is_the_monotonic_clock_when_the_reader_is_idle() -> None:
    c = Clocks()
    d = driver(c)
    d.clock_state = (True, c.wall - 2.0)
    assert d.bus_clock() == 1000.0


def test_bus_clock_lags_by_the_age_of_the_last_processed_frame() -> None:
    c = Clocks()
    d = driver(c)
    d.clock_state = (False, c.wall - 2.0)  # the reader is 2 s behind the bus
    assert d.bus_clock() == 998.0


def test_a_paused_gateway_judges_by_the_frames_not_by_the_pause() -> None:
    # SIGSTOP for 1 s: on resume the frames of that second are still queued; the one being
    # processed was received 1 s ago, so the bus clock is 1 s behind the monotonic clock
    c = Clocks()
    d = driver(c)
    d.clock_state = (False, c.wall)
    c.mono += 1.0
    c.wall += 1.0
    assert d.bus_clock() == 1000.0


def test_frame_time_maps_a_wall_clock_timestamp_to_monotonic() -> None:
    c = Clocks()
    d = driver(c)
    msg = can.Message(arbitration_id=0x701, data=b"\x05", timestamp=c.wall - 0.5)
    assert d.frame_time(msg) == 999.5


def test_an_absurd_timestamp_falls_back_to_the_monotonic_clock() -> None:
    c = Clocks()
    d = driver(c)
    msg = can.Message(arbitration_id=0x701, data=b"\x05", timestamp=c.wall + 5.0)  # future
    assert d.frame_time(msg) == 1000.0


def test_a_wall_clock_stepped_either_way_makes_frames_received_now_not_from_the_past_or_future() -> None:
    """A socketcand server stamps frames with its own clock; this machine's wall clock steps
    back (frames from the future) or forward by more than ``FRAME_AGE_MAX_S`` (frames from the
    past): neither is believed, the frame is taken as received now (``stamp``, the bus clock,
    the pair's last-frame time all read it so)."""
    c = Clocks()
    d = driver(c)
    server_wall = c.wall
    c.wall -= 10.0  # stepped back
    d._sync_clocks()
    assert d.stamp(server_wall) == 1000.0
    c.wall += 20.0  # stepped forward: the server's stamps look 10 s old
    d._sync_clocks()
    assert d.stamp(server_wall) == 1000.0
    d.clock_state = (False, server_wall)  # busy with such a frame: the bus clock is now too
    assert d.bus_clock() == 1000.0
    assert d.stamp(c.wall - FRAME_AGE_MAX_S + 0.5) == 1000.0 - FRAME_AGE_MAX_S + 0.5  # a backlog


def test_error_passive_clears_only_after_the_hold_time_without_error_frames() -> None:
    c = Clocks()
    d = driver(c)
    d.controller.error_hold_s = 0.2
    d.state = "ok"
    d._error_frame(can.Message(arbitration_id=0x04, data=bytes([0, 0x10]), is_error_frame=True))
    assert d.state == "error"
    c.mono += 0.19
    d.controller.on_frame()  # frames flow, but within the hold time
    d._apply_controller()
    assert d.state == "error"
    c.mono += 0.01
    d.controller.on_frame()
    d._apply_controller()
    assert d.state == "ok"


class FailingBus:
    """A backend that hands one frame over and then dies under the reader."""

    def __init__(self, d: BusDriver, c: Clocks) -> None:
        self.d, self.c, self.calls = d, c, 0

    def recv(self, timeout: float | None = None) -> can.Message | None:
        self.calls += 1
        if self.calls == 1:  # a frame of a burst: the reader is "busy" with it
            return can.Message(arbitration_id=0x181, data=bytes(8), timestamp=self.c.wall)
        raise can.CanOperationError("Cannot operate on a closed bus")

    def shutdown(self) -> None:
        pass


def test_a_bus_that_dies_in_a_burst_does_not_stop_the_bus_clock() -> None:
    # The backend fails while the reader is within a burst: nothing is buffered any more, so
    # the bus clock must go on with the monotonic clock; frozen at the last frame, no node
    # could time out while the bus is down (a node silent through the outage never found lost)
    c = Clocks()
    d = driver(c)
    seen: list[tuple[str, float]] = []

    def on_state(state: str, detail: str) -> None:
        c.mono += 1.5  # the outage goes on
        c.wall += 1.5
        seen.append((state, d.bus_clock()))
        d._running.clear()  # no reopen in this test

    d.on_state = on_state
    d.bus = FailingBus(d, c)  # type: ignore[assignment]
    d.state = "ok"
    d._running.set()
    d._run()
    assert seen == [("down", 1001.5)]
    assert d.idle
