"""Supervision judges timeouts by the frames the reader has processed: a backlog in the receive
queue must not turn a healthy node into a lost one."""

from __future__ import annotations

import time

import can

from gateway.bus.driver import BusDriver
from gateway.image import ProcessImage


def test_bus_clock_is_real_time_when_the_reader_is_idle() -> None:
    d = BusDriver({"interface": "virtual", "channel": "unused"}, ProcessImage())
    d.idle = True
    before = time.monotonic()
    assert before <= d.bus_clock() <= time.monotonic()


def test_bus_clock_lags_by_the_age_of_the_last_processed_frame() -> None:
    d = BusDriver({"interface": "virtual", "channel": "unused"}, ProcessImage())
    d.idle = False
    d.last_frame_wall = time.time() - 2.0  # the reader is 2 s behind the bus
    lag = time.monotonic() - d.bus_clock()
    assert 1.9 < lag < 2.1


def test_frame_time_maps_a_wall_clock_timestamp_to_monotonic() -> None:
    d = BusDriver({"interface": "virtual", "channel": "unused"}, ProcessImage())
    msg = can.Message(arbitration_id=0x701, data=b"\x05", timestamp=time.time() - 0.5)
    age = time.monotonic() - d.frame_time(msg)
    assert 0.45 < age < 0.55
