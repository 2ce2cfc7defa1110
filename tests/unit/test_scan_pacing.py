"""The active scan's requests are paced by the bit rate and its answer window is sized by it
(``bus/scan.py`` ``send_probes``): a fake clock, and a fake interface that models a SocketCAN
transmit queue (10 frames, drained at the bit rate; a frame sent to a full queue is refused
with ENOBUFS, as python-can's socketcan backend raises it)."""

from __future__ import annotations

import errno

import can
import pytest

from canopen_gateway.bus.scan import (
    ASSUMED_BITRATE_BPS,
    FRAME_BITS_MAX,
    SEND_ATTEMPTS,
    send_probes,
)

IDS = range(1, 128)


class Clock:
    def __init__(self) -> None:
        self.now = 50.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


class TxQueue(can.BusABC):
    """A CAN interface's transmit queue of ``size`` frames, sent on the wire one per frame
    time of the bit rate (``FRAME_BITS_MAX`` bits; the answers are not modelled)."""

    def __init__(self, clock: Clock, bitrate_bps: int, size: int = 10) -> None:
        self.clock = clock
        self.frame_s = FRAME_BITS_MAX / bitrate_bps
        self.size = size
        self.queued: list[float] = []  # when each queued frame is off the wire
        self.sent: list[tuple[float, int]] = []  # (time accepted, node id)
        self.refused = 0
        self.most_queued = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        now = self.clock.now
        self.queued = [t for t in self.queued if t > now]
        if len(self.queued) >= self.size:
            self.refused += 1
            raise can.CanOperationError(
                "Failed to transmit: No buffer space available", errno.ENOBUFS
            )
        start = max(now, self.queued[-1] if self.queued else now)
        self.queued.append(start + self.frame_s)
        self.most_queued = max(self.most_queued, len(self.queued))
        self.sent.append((now, msg.arbitration_id - 0x600))

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False


def test_127_requests_at_125_kbits_fit_the_transmit_queue_and_get_their_wire_time() -> None:
    clock = Clock()
    bus = TxQueue(clock, 125_000)
    send_probes(bus, IDS, bitrate_bps=125_000, timeout_s=0.1, clock=clock, sleep=clock.sleep)
    assert [node_id for _, node_id in bus.sent] == list(IDS)  # each once, in order
    assert bus.refused == 0 and bus.most_queued <= 8  # never more than a group queued
    # the requests alone are 127 x 135 bits = 137 ms at 125 kbit/s: the answers' window covers
    # each request and its answer on the wire, then the devices' 0.1 s
    elapsed_s = clock.now - 50.0
    assert elapsed_s >= 2 * 127 * FRAME_BITS_MAX / 125_000 + 0.1 - 1e-9
    assert elapsed_s == pytest.approx(0.3743, abs=0.001)


def test_a_faster_bus_waits_less_and_an_unknown_bit_rate_is_taken_as_125_kbits() -> None:
    def window_s(bitrate_bps: int | None) -> float:
        clock = Clock()
        bus = TxQueue(clock, bitrate_bps or ASSUMED_BITRATE_BPS)
        send_probes(
            bus, IDS, bitrate_bps=bitrate_bps, timeout_s=0.1, clock=clock, sleep=clock.sleep
        )
        assert bus.refused == 0
        return clock.now - 50.0

    assert window_s(1_000_000) == pytest.approx(0.1343, abs=0.001)
    assert window_s(None) == window_s(125_000)
    assert window_s(50_000) == pytest.approx(0.7858, abs=0.001)


def test_a_request_refused_with_enobufs_is_sent_again_once_the_queue_drained() -> None:
    """A queue of 4 frames (smaller than a group): some requests are refused; each is sent
    again after a group's wire time, none is lost, none is sent twice."""
    clock = Clock()
    bus = TxQueue(clock, 125_000, size=4)
    send_probes(bus, IDS, bitrate_bps=125_000, timeout_s=0.1, clock=clock, sleep=clock.sleep)
    assert bus.refused > 0
    assert [node_id for _, node_id in bus.sent] == list(IDS)


def test_an_interface_that_never_takes_the_frame_fails_the_scan_with_its_error() -> None:
    """A transmit queue that never drains (no other node acknowledges): after
    ``SEND_ATTEMPTS`` the scan raises the interface's error, naming the request."""
    clock = Clock()
    bus = TxQueue(clock, 125_000, size=0)
    with pytest.raises(can.CanOperationError) as err:
        send_probes(bus, IDS, bitrate_bps=125_000, timeout_s=0.1, clock=clock, sleep=clock.sleep)
    assert bus.refused == SEND_ATTEMPTS
    assert str(err.value).startswith(
        f"the scan's SDO request to node id 1 was refused {SEND_ATTEMPTS} times: "
        "Failed to transmit: No buffer space available"
    )
