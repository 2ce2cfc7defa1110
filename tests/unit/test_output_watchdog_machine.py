"""The Modbus output watchdog's machine on a fake clock: every row of its transition table and
both sides of the timeout edge. The server feeds it the requests, connections and
disconnections of clients allowed to write only (tests/integration/test_output_watchdog.py)."""

from __future__ import annotations

import math

import pytest

from canopen_gateway.modbus.watchdog import (
    DISCONNECT,
    TIMEOUT,
    TRANSITIONS,
    OutputWatchdog,
    WatchdogEvent,
    WatchdogState,
)
from tests.pair_invariants import safe_in_time

T0 = 1000.0


def test_off_when_neither_timeout_nor_disconnect_is_configured() -> None:
    wd = OutputWatchdog(0.0, on_disconnect=False)
    assert wd.state is WatchdogState.OFF and not wd.enabled
    wd.on_writer_connect(T0)
    wd.on_request(T0)
    assert wd.next_deadline() is None
    assert wd.tick(T0 + 1e9) is None
    assert wd.on_writer_disconnect(T0 + 1e9) is None
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
    wd.on_writer_connect(T0)
    wd.on_writer_connect(T0)
    wd.on_request(T0)
    assert wd.next_deadline() is None, "no timeout configured"
    assert wd.on_writer_disconnect(T0 + 1) is None, "one client is still connected"
    assert wd.on_writer_disconnect(T0 + 2) == DISCONNECT
    assert wd.state is WatchdogState.TRIPPED
    wd.on_writer_connect(T0 + 3)
    assert wd.on_writer_disconnect(T0 + 4) is None, "already tripped: no second write"
    assert wd.trips == {TIMEOUT: 0, DISCONNECT: 1}


def test_a_client_gone_without_a_request_before_any_plc_talked_trips_nothing() -> None:
    # docs/modbus.md: a gateway no PLC ever talked to does not write its outputs; a port check
    # that connects and closes is not a PLC going away
    wd = OutputWatchdog(0.5, on_disconnect=True)
    wd.on_writer_connect(T0)
    assert wd.on_writer_disconnect(T0 + 0.1) is None
    assert wd.state is WatchdogState.WAITING and wd.next_deadline() is None
    wd.on_writer_connect(T0 + 1)
    wd.on_request(T0 + 1)  # a PLC talked: from now on its going away trips
    assert wd.on_writer_disconnect(T0 + 1.1) is None, "a countdown, not at once"
    assert wd.tick(T0 + 1.5) == DISCONNECT


def test_disconnect_does_not_trip_when_not_configured() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_writer_connect(T0)
    wd.on_request(T0)
    assert wd.on_writer_disconnect(T0 + 0.1) is None
    assert wd.tick(T0 + 0.5) == TIMEOUT, "the timeout still runs with no client connected"


def test_a_plc_that_connects_per_transaction_never_trips() -> None:
    # docs/modbus.md: a PLC that opens a connection for each transaction, 10 a second
    wd = OutputWatchdog(0.3, on_disconnect=True)
    now = T0
    for _ in range(10):
        wd.on_writer_connect(now)
        wd.on_request(now)
        wd.on_request(now + 0.002)  # answered
        assert wd.on_writer_disconnect(now + 0.003) is None
        assert wd.state is WatchdogState.DISCONNECTED
        assert wd.next_deadline() == now + 0.002 + 0.3
        now += 0.1
        assert wd.tick(now) is None
    assert wd.trips == {TIMEOUT: 0, DISCONNECT: 0}


def test_a_gone_writer_trips_at_the_deadline_of_its_last_request_unless_one_comes_back() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=True)
    wd.on_writer_connect(T0)
    wd.on_request(T0)
    assert wd.on_writer_disconnect(T0 + 0.2) is None
    deadline = wd.next_deadline()
    assert deadline == T0 + 0.5, "a disconnection never makes the watchdog slower"
    # a writer that connects and asks nothing does not cancel the countdown
    wd.on_writer_connect(T0 + 0.3)
    assert wd.state is WatchdogState.DISCONNECTED
    assert wd.tick(math.nextafter(deadline, -math.inf)) is None
    assert wd.tick(deadline) == DISCONNECT
    assert wd.state is WatchdogState.TRIPPED
    # it asks now: armed again; it goes and comes back with a request in time: no trip
    wd.on_request(T0 + 1)
    assert wd.on_writer_disconnect(T0 + 1.1) is None
    wd.on_writer_connect(T0 + 1.2)
    wd.on_request(T0 + 1.2)
    assert wd.state is WatchdogState.ARMED
    assert wd.tick(T0 + 1.5) is None
    assert wd.tick(T0 + 1.7) == TIMEOUT, "connected and silent: a timeout"
    assert wd.trips == {TIMEOUT: 1, DISCONNECT: 1}


def test_one_writer_of_two_going_starts_no_countdown() -> None:
    wd = OutputWatchdog(0.0, on_disconnect=True)
    wd.on_writer_connect(T0)
    wd.on_writer_connect(T0)
    wd.on_request(T0)
    assert wd.on_writer_disconnect(T0 + 1) is None
    assert wd.state is WatchdogState.ARMED and wd.next_deadline() is None
    assert wd.on_writer_disconnect(T0 + 2) == DISCONNECT


def _reach(state: WatchdogState, wd: OutputWatchdog) -> None:
    """Walk a fresh machine (timeout 0.5 s, trip on disconnect, one writer connected at T0)
    into ``state`` through its public events."""
    wd.on_writer_connect(T0)
    if state is WatchdogState.WAITING:
        return
    if state is WatchdogState.STANDBY:
        wd.on_mastering(False)  # a pair's member from its start: no PLC request known yet
        assert wd.state is state
        return
    wd.on_request(T0)
    if state is WatchdogState.DISCONNECTED:
        wd.on_writer_disconnect(T0 + 0.1)
        wd.on_writer_connect(T0 + 0.2)  # connected again, no request yet
    elif state is WatchdogState.TRIPPED:
        wd.tick(T0 + 0.5)
    assert wd.state is state


@pytest.mark.parametrize(("pair", "outcome"), list(TRANSITIONS.items()), ids=str)
def test_the_machine_does_what_its_table_says(
    pair: tuple[WatchdogState, WatchdogEvent], outcome: tuple[WatchdogState, str | None]
) -> None:
    state, event = pair
    wd = OutputWatchdog(0.5, on_disconnect=True)
    _reach(state, wd)
    before = dict(wd.trips)
    if event is WatchdogEvent.REQUEST:
        wd.on_request(T0 + 0.3)
        reason = None
    elif event is WatchdogEvent.LAST_WRITER_GONE:
        reason = wd.on_writer_disconnect(T0 + 0.3)
    elif event in (WatchdogEvent.STAND_BY, WatchdogEvent.TAKE_OVER):
        wd.on_mastering(event is WatchdogEvent.TAKE_OVER)
        reason = None
    elif event is WatchdogEvent.TAKE_OVER_WRITTEN:  # a write heard on the bus
        wd.on_mastering(True, written_s=T0 + 0.2)
        reason = None
    else:
        deadline = wd.next_deadline()
        assert deadline is not None
        reason = wd.tick(deadline)
    assert (wd.state, reason) == outcome
    assert sum(wd.trips.values()) - sum(before.values()) == (reason is not None)


def test_every_pair_the_machine_can_meet_is_in_its_table() -> None:
    live = [s for s in WatchdogState if s is not WatchdogState.OFF]
    for state in live:
        for event in (WatchdogEvent.REQUEST, WatchdogEvent.LAST_WRITER_GONE):
            assert (state, event) in TRANSITIONS
    timed = {s for s, e in TRANSITIONS if e is WatchdogEvent.DEADLINE}
    assert timed == {WatchdogState.ARMED, WatchdogState.DISCONNECTED}, "the states with a deadline"


def test_the_standby_of_a_pair_never_trips_and_runs_no_timer() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=True)
    wd.on_writer_connect(T0)
    wd.on_request(T0)
    assert wd.next_deadline() == T0 + 0.5
    wd.on_mastering(False)  # the gateway stood down: its commands refuse
    assert wd.state is WatchdogState.STANDBY and wd.next_deadline() is None
    for k in range(1, 20):  # a PLC polls the standby: nothing arms it, nothing trips
        wd.on_request(T0 + k)
        assert wd.tick(T0 + k + 0.6) is None
    assert wd.on_writer_disconnect(T0 + 30) is None
    assert wd.trips == {TIMEOUT: 0, DISCONNECT: 0}


def test_a_gateway_that_becomes_active_with_no_sign_of_a_plc_waits_as_at_start() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_mastering(False)  # a pair's gateway starts as the standby
    wd.on_mastering(True, written_s=None)  # it takes over: no request, no write heard
    assert wd.state is WatchdogState.WAITING and wd.next_deadline() is None
    assert wd.tick(T0 + 10) is None
    wd.on_request(T0 + 10)  # the first PLC request arms it
    assert wd.tick(math.nextafter(T0 + 10.5, 0)) is None
    assert wd.tick(T0 + 10.5) == TIMEOUT


def test_a_take_over_counts_from_the_plcs_last_write_heard_on_the_bus() -> None:
    """The PLC wrote through the other member (its RPDOs heard at T0), then died with it: the
    outputs go safe 0.5 s after that write, not after a first write that never comes."""
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_mastering(False)
    wd.on_mastering(True, written_s=T0)  # the take-over, 0.3 s after the write
    assert wd.state is WatchdogState.ARMED and wd.next_deadline() == T0 + 0.5
    assert wd.tick(math.nextafter(T0 + 0.5, 0)) is None
    assert wd.tick(T0 + 0.5) == TIMEOUT
    assert safe_in_time(T0, T0 + 0.5, T0 + 0.5, watchdog_s=0.5, takeover_s=0.3) == []
    # a take-over later than the watchdog: safe at its first tick, within watchdog + take-over
    late = OutputWatchdog(0.5, on_disconnect=False)
    late.on_mastering(False)
    late.on_mastering(True, written_s=T0)
    assert late.tick(T0 + 0.8) == TIMEOUT
    assert safe_in_time(T0, T0 + 0.8, T0 + 0.8, watchdog_s=0.5, takeover_s=0.3) == []


def test_a_take_over_counts_from_the_later_of_a_request_to_it_and_a_write_heard() -> None:
    wd = OutputWatchdog(0.5, on_disconnect=False)
    wd.on_mastering(False)
    wd.on_request(T0 + 2)  # the PLC polls the standby (its write there refused 0x06)
    wd.on_mastering(True, written_s=T0 + 1)
    assert wd.next_deadline() == T0 + 2.5
    late = OutputWatchdog(0.5, on_disconnect=False)
    late.on_mastering(False)
    late.on_request(T0 + 1)
    late.on_mastering(True, written_s=T0 + 2)
    assert late.next_deadline() == T0 + 2.5
    # the take-over came after the deadline: it trips at its first tick
    assert late.tick(T0 + 3) == TIMEOUT


def test_a_take_over_without_a_writer_connected_trips_on_disconnect_at_once() -> None:
    """``watchdog_ms: 0`` with ``watchdog_on_disconnect``: the PLC's connection went with the
    other member; none is connected to this one."""
    wd = OutputWatchdog(0.0, on_disconnect=True)
    wd.on_mastering(False)
    wd.on_mastering(True, written_s=T0)
    assert wd.state is WatchdogState.DISCONNECTED
    assert wd.tick(T0 + 0.3) == DISCONNECT
    connected = OutputWatchdog(0.0, on_disconnect=True)
    connected.on_mastering(False)
    connected.on_writer_connect(T0)  # the PLC is connected to this member too
    connected.on_mastering(True, written_s=T0)
    assert connected.state is WatchdogState.ARMED and connected.tick(T0 + 10) is None


def test_a_disabled_watchdog_ignores_the_role() -> None:
    wd = OutputWatchdog(0.0, on_disconnect=False)
    wd.on_mastering(False)
    wd.on_mastering(True)
    assert wd.state is WatchdogState.OFF


def test_negative_timeout_is_refused() -> None:
    with pytest.raises(ValueError):
        OutputWatchdog(-1.0, on_disconnect=False)
