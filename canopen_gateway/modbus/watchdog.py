"""The Modbus output watchdog: when does the PLC count as gone? (``modbus.watchdog_ms``,
``modbus.watchdog_on_disconnect``)

Rule 1: everything that decides when the outputs go safe lives here, as a table of
transitions (``TRANSITIONS``) the machine reads. Rule 2: this module knows no sockets, no
clock, no outputs and no access rights: the caller decides which client may write, feeds
(event, now) for those clients only, is told when it trips, writes the safe outputs and sets a
timer at ``next_deadline()`` (in the style of CANopenNode's ``CO_HBconsumer_process``: given
the time, says when it next needs to run; nothing polls).

A *writer* is a client allowed to write (the server decides: not ``modbus.read_only``, its
address in ``modbus.allowed_networks``, on TLS a role with ``write`` access). Only writers are
fed: an HMI that only may read keeps nothing alive, and its coming and going changes nothing.

States::

    OFF           watchdog_ms 0 and watchdog_on_disconnect off: never trips, nothing is fed
    WAITING       no writer's request since the gateway started: no timer runs (a gateway no
                  PLC talked to does not write its outputs)
    ARMED         a writer's request was served; trips ``timeout_s`` after the last one
    DISCONNECTED  armed, and the last writer disconnected (fed only with
                  watchdog_on_disconnect): trips ``timeout_s`` after the last request, or at
                  once when ``timeout_s`` is 0; a writer that connects again and sends a
                  request arms it again (a PLC that connects per transaction does not trip)
    TRIPPED       the safe outputs were written once; the next writer's request arms it again
                  (the outputs stay safe until a client writes them)
    STANDBY       the gateway is not the active one of a hot-standby pair (``master.redundancy``):
                  its commands refuse, so it has no outputs to make safe; nothing arms it, but a
                  writer's request (refused, yet a sign of the PLC) is remembered. When the
                  gateway becomes active it counts from the PLC's last sign it has, a request to
                  it or a write to an output heard on the bus (the other member's RPDOs): ARMED
                  from then (so the outputs go safe ``timeout_s`` after the PLC's last write to
                  either member, at once when that is past; DISCONNECTED from then when it
                  trips on a disconnection and no writer is connected to it); with no sign at
                  all, WAITING as at start

Events: ``request`` (a writer's request, when it arrives and again when it is answered),
``last_writer_gone`` (the number of connected writers fell to 0), ``deadline`` (``tick`` at or
after ``next_deadline()``), ``stand_by`` / ``take_over`` / ``take_over_written`` (the gateway
stops / starts mastering the bus, without or with a sign of the PLC: ``on_mastering``).

Imports: the standard library only.
"""

from __future__ import annotations

from enum import StrEnum


class WatchdogState(StrEnum):
    OFF = "off"
    WAITING = "waiting"
    ARMED = "armed"
    DISCONNECTED = "disconnected"
    TRIPPED = "tripped"
    STANDBY = "standby"


class WatchdogEvent(StrEnum):
    REQUEST = "request"
    LAST_WRITER_GONE = "last_writer_gone"
    DEADLINE = "deadline"
    STAND_BY = "stand_by"
    TAKE_OVER = "take_over"
    TAKE_OVER_WRITTEN = "take_over_written"


TIMEOUT, DISCONNECT = "timeout", "disconnect"

_S, _E = WatchdogState, WatchdogEvent

#: (state, event) -> (next state, trip reason or None). Every pair the machine can meet is
#: here; a pair that is not is a misuse of the machine by its caller (KeyError).
TRANSITIONS: dict[tuple[WatchdogState, WatchdogEvent], tuple[WatchdogState, str | None]] = {
    # state                 event                    next               trips
    (_S.WAITING,      _E.REQUEST):          (_S.ARMED,         None),
    (_S.ARMED,        _E.REQUEST):          (_S.ARMED,         None),  # the deadline moves
    (_S.DISCONNECTED, _E.REQUEST):          (_S.ARMED,         None),  # a writer came back
    (_S.TRIPPED,      _E.REQUEST):          (_S.ARMED,         None),
    (_S.WAITING,      _E.LAST_WRITER_GONE): (_S.WAITING,       None),  # a port check
    (_S.ARMED,        _E.LAST_WRITER_GONE): (_S.DISCONNECTED,  None),
    (_S.DISCONNECTED, _E.LAST_WRITER_GONE): (_S.DISCONNECTED,  None),  # came, asked nothing, went
    (_S.TRIPPED,      _E.LAST_WRITER_GONE): (_S.TRIPPED,       None),  # written once
    (_S.ARMED,        _E.DEADLINE):         (_S.TRIPPED,       TIMEOUT),
    (_S.DISCONNECTED, _E.DEADLINE):         (_S.TRIPPED,       DISCONNECT),
    (_S.WAITING,      _E.STAND_BY):         (_S.STANDBY,       None),
    (_S.ARMED,        _E.STAND_BY):         (_S.STANDBY,       None),  # no timer any more
    (_S.DISCONNECTED, _E.STAND_BY):         (_S.STANDBY,       None),
    (_S.TRIPPED,      _E.STAND_BY):         (_S.STANDBY,       None),
    (_S.STANDBY,      _E.STAND_BY):         (_S.STANDBY,       None),
    (_S.STANDBY,      _E.REQUEST):          (_S.STANDBY,       None),  # writes refuse (0x06)
    (_S.STANDBY,      _E.LAST_WRITER_GONE): (_S.STANDBY,       None),
    (_S.STANDBY,      _E.TAKE_OVER):        (_S.WAITING,       None),  # no PLC known: as at start
    (_S.STANDBY,      _E.TAKE_OVER_WRITTEN): (_S.ARMED,        None),  # from the PLC's last sign
    (_S.WAITING,      _E.TAKE_OVER):        (_S.WAITING,       None),
}  # fmt: skip


class OutputWatchdog:
    """Fed ``on_request``, ``on_writer_connect``, ``on_writer_disconnect`` and ``tick`` with
    the time in seconds (any monotonic clock), for writers only; ``tick`` and
    ``on_writer_disconnect`` return the reason when the outputs must go safe now
    (``"timeout"``, ``"disconnect"``), else None."""

    def __init__(self, timeout_s: float, on_disconnect: bool):
        if timeout_s < 0:
            raise ValueError("timeout_s must be >= 0")
        self.timeout_s = timeout_s
        self.trip_on_disconnect = on_disconnect
        self.enabled = timeout_s > 0 or on_disconnect
        self.state = WatchdogState.WAITING if self.enabled else WatchdogState.OFF
        self.last_request_s: float | None = None
        self.gone_s: float | None = None  # when the last writer disconnected (DISCONNECTED)
        self.writers = 0
        self.trips: dict[str, int] = {TIMEOUT: 0, DISCONNECT: 0}

    def _fire(self, event: WatchdogEvent) -> str | None:
        self.state, reason = TRANSITIONS[(self.state, event)]
        if reason is not None:
            self.trips[reason] += 1
        return reason

    def on_request(self, now: float) -> None:
        """A writer's request arrived or was answered."""
        if self.enabled:
            self.last_request_s = now
            self._fire(WatchdogEvent.REQUEST)

    def on_mastering(self, mastering: bool, written_s: float | None = None) -> None:
        """The gateway started (True) or stopped (False) mastering the bus (a pair's role).
        ``written_s``: when a write to an output was last heard on the bus or made here (None:
        never); with a writer's request since this gateway started, the later of the two is
        the PLC's last sign, from which a take-over counts."""
        if not self.enabled:
            return
        if not mastering:
            self._fire(WatchdogEvent.STAND_BY)
            return
        signs = [t for t in (self.last_request_s, written_s) if t is not None]
        if not signs or self.state is not WatchdogState.STANDBY:
            self._fire(WatchdogEvent.TAKE_OVER)
            return
        self.last_request_s = max(signs)
        self._fire(WatchdogEvent.TAKE_OVER_WRITTEN)
        if self.trip_on_disconnect and not self.writers:  # the PLC's connection went with the other
            self.gone_s = self.last_request_s
            self._fire(WatchdogEvent.LAST_WRITER_GONE)

    def on_writer_connect(self, now: float) -> None:
        self.writers += 1

    def on_writer_disconnect(self, now: float) -> str | None:
        self.writers = max(0, self.writers - 1)
        if self.writers or not self.trip_on_disconnect:
            return None
        if self.state is not WatchdogState.DISCONNECTED:
            self.gone_s = now
        self._fire(WatchdogEvent.LAST_WRITER_GONE)
        return self.tick(now)  # with timeout_s 0 the deadline is now

    def tick(self, now: float) -> str | None:
        deadline = self.next_deadline()
        if deadline is not None and now >= deadline:
            return self._fire(WatchdogEvent.DEADLINE)
        return None

    def next_deadline(self) -> float | None:
        """When ``tick`` is next due (None: no timer needed). DISCONNECTED keeps the deadline
        of the last request: a disconnection never makes the watchdog slower."""
        if self.state not in (WatchdogState.ARMED, WatchdogState.DISCONNECTED):
            return None
        if self.timeout_s > 0:
            assert self.last_request_s is not None
            return self.last_request_s + self.timeout_s
        if self.state is WatchdogState.DISCONNECTED:
            return self.gone_s  # no timeout: at once
        return None
