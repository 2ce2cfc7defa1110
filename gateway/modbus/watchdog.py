"""The Modbus output watchdog: when does the PLC count as gone? (``modbus.watchdog_ms``,
``modbus.watchdog_on_disconnect``)

Rule 1: everything that decides when the outputs go safe lives here, as a table of
transitions. Rule 2: this module knows no sockets, no clock and no outputs: the caller feeds
(event, now), is told when it trips, writes the safe outputs and sets a timer at
``next_deadline()`` (in the style of CANopenNode's ``CO_HBconsumer_process``: given the time,
says when it next needs to run; nothing polls).

States::

    OFF      watchdog_ms 0 and watchdog_on_disconnect off: never trips
    WAITING  no request since the gateway started: no timer runs (a gateway without a PLC
             does not write its outputs)
    ARMED    a request was served; trips ``timeout_s`` after the last one
    TRIPPED  the safe outputs were written once; the next request arms it again (the outputs
             stay safe until a client writes them)

    state     event          condition                         next      trips
    WAITING   request        -                                 ARMED
    ARMED     request        -                                 ARMED               (deadline moves)
    TRIPPED   request        -                                 ARMED
    ARMED     tick           now >= last request + timeout     TRIPPED   "timeout"
    ARMED     last client    watchdog_on_disconnect            TRIPPED   "disconnect"

Any other (state, event) pair changes nothing: a client that connects and goes without a request
(a port check, a tool looking around) while WAITING writes nothing, as no PLC talked yet. Requests count whatever their unit, function or
outcome: a PLC that polls is alive (the server feeds a request when it arrives and again when
it is answered, so a write waiting for its device is no silence).

Imports: the standard library only.
"""

from __future__ import annotations

from enum import StrEnum


class WatchdogState(StrEnum):
    OFF = "off"
    WAITING = "waiting"
    ARMED = "armed"
    TRIPPED = "tripped"


TIMEOUT, DISCONNECT = "timeout", "disconnect"


class OutputWatchdog:
    """Fed ``on_request``, ``on_connect``, ``on_disconnect`` and ``tick`` with the time in
    seconds (any monotonic clock); ``tick`` and ``on_disconnect`` return the reason when the
    outputs must go safe now (``"timeout"``, ``"disconnect"``), else None."""

    def __init__(self, timeout_s: float, on_disconnect: bool):
        if timeout_s < 0:
            raise ValueError("timeout_s must be >= 0")
        self.timeout_s = timeout_s
        self.trip_on_disconnect = on_disconnect
        self.enabled = timeout_s > 0 or on_disconnect
        self.state = WatchdogState.WAITING if self.enabled else WatchdogState.OFF
        self.last_request_s: float | None = None
        self.clients = 0
        self.trips: dict[str, int] = {TIMEOUT: 0, DISCONNECT: 0}

    def on_request(self, now: float) -> None:
        if self.state is WatchdogState.OFF:
            return
        self.last_request_s = now
        self.state = WatchdogState.ARMED

    def on_connect(self, now: float) -> None:
        self.clients += 1

    def on_disconnect(self, now: float) -> str | None:
        self.clients = max(0, self.clients - 1)
        if (
            self.clients == 0
            and self.trip_on_disconnect
            and self.state is WatchdogState.ARMED
        ):
            return self._trip(DISCONNECT)
        return None

    def tick(self, now: float) -> str | None:
        deadline = self.next_deadline()
        if deadline is not None and now >= deadline:
            return self._trip(TIMEOUT)
        return None

    def next_deadline(self) -> float | None:
        """When ``tick`` is next due (None: no timer needed)."""
        if self.state is WatchdogState.ARMED and self.timeout_s > 0:
            assert self.last_request_s is not None
            return self.last_request_s + self.timeout_s
        return None

    def _trip(self, reason: str) -> str:
        self.state = WatchdogState.TRIPPED
        self.trips[reason] += 1
        return reason
