"""The Modbus output watchdog's machine on a fake clock: every row of its transition table and
both sides of the timeout edge."""

from __future__ import annotations

import math

import pytest

from gateway.modbus.watchdog import DISCONNECT, TIMEOUT, OutputWatchdog, WatchdogState

T0 = 1000.0


def test_off_when_neither_timeout_nor_disconnect_is_configured() -> None:
    wd = OutputWatchdog(0.0, on_disconnect=False)
    assert wd.state is WatchdogState.OFF and not wd.enabled
    wd.on_connect(T0)
    wd.on_request(T0)
    assert wd.next_deadline() is None
    assert wd.tick(T0 + 1e9) is None
    assert wd.on_disconnect(T0 + 1e9) is None
    assert wd.state is WatchdogState.OFF


def test_no_timer_before_the_first_request() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    assert wd.state is WatchdogState.WAITING
    assert wd.next_deadline() is None
    assert wd.tick(T0 + 3600) is None, "a gateway without a PLC does not write its outputs"


def test_trips_exactly_at_the_timeout_after_the_last_request() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_request(T0)
    assert wd.state is WatchdogState.ARMED
    deadline = wd.next_deadline()
    assert deadline == T0 + 0.5
    assert wd.tick(math.nextafter(deadline, -math.inf)) is None
    assert wd.state is WatchdogState.ARMED
    assert wd.tick(deadline) == TIMEOUT
    assert wd.state is WatchdogState.TRIPPED
    assert wd.trips == {TIMEOUT: 1, DISCONNECT: 0}


def test_each_request_moves_the_deadline() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_request(T0)
    wd.on_request(T0 + 0.4)
    assert wd.tick(T0 + 0.5) is None, "the first deadline passed, but a request came since"
    assert wd.next_deadline() == T0 + 0.9
    assert wd.tick(T0 + 0.9) == TIMEOUT


def test_trips_once_per_silence_and_the_next_request_arms_again() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_request(T0)
    assert wd.tick(T0 + 0.5) == TIMEOUT
    assert wd.next_deadline() is None
    assert wd.tick(T0 + 100) is None, "written once: no second trip while silent"
    wd.on_request(T0 + 100)
    assert wd.state is WatchdogState.ARMED
    assert wd.tick(T0 + 100.5) == TIMEOUT
    assert wd.trips[TIMEOUT] == 2


def test_last_client_gone_trips_at_once_when_configured() -> None:
    wd = OutputWatchdog(0.0, on_disconnect=True)
    wd.on_connect(T0)
    wd.on_connect(T0)
    wd.on_request(T0)
    assert wd.next_deadline() is None, "no timeout configured"
    assert wd.on_disconnect(T0 + 1) is None, "one client is still connected"
    assert wd.on_disconnect(T0 + 2) == DISCONNECT
    assert wd.state is WatchdogState.TRIPPED
    wd.on_connect(T0 + 3)
    assert wd.on_disconnect(T0 + 4) is None, "already tripped: no second write"
    assert wd.trips == {TIMEOUT: 0, DISCONNECT: 1}


def test_a_client_gone_without_a_request_before_any_plc_talked_trips_nothing() -> None:
    # docs/modbus.md: a gateway no PLC ever talked to does not write its outputs; a port check
    # that connects and closes is not a PLC going away
    wd = OutputWatchdog(0.5, on_disconnect=True)
    wd.on_connect(T0)
    assert wd.on_disconnect(T0 + 0.1) is None
    assert wd.state is WatchdogState.WAITING and wd.next_deadline() is None
    wd.on_connect(T0 + 1)
    wd.on_request(T0 + 1)  # a PLC talked: from now on its going away trips
    assert wd.on_disconnect(T0 + 1.1) == DISCONNECT


def test_disconnect_does_not_trip_when_not_configured() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_connect(T0)
    wd.on_request(T0)
    assert wd.on_disconnect(T0 + 0.1) is None
    assert wd.tick(T0 + 0.5) == TIMEOUT, "the timeout still runs with no client connected"


def test_negative_timeout_is_refused() -> None:
    with pytest.raises(ValueError):
        OutputWatchdog(-1.0, on_disconnect=False)
