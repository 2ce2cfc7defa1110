"""The CAN bus driver: owns the python-can bus, the reader thread and sending.

A reader thread receives frames and dispatches them by COB-ID through a dict: process data
(TPDOs) is decoded and written into the process image right on this thread (the hot path: no
event-loop hop, no logging per frame); everything else (heartbeat, EMCY, SDO, LSS) is handed to
its handler, which for control traffic forwards to the event loop. The reader takes frames in
bursts: after a frame it asks the backend for the next one without waiting, and when none is
buffered it calls the ``burst_listeners`` (once per burst: consumers that hand work to another
thread wake it there, not once per frame) and then blocks. While frames keep coming (the reader
behind a backlog, a bus that never pauses) it also calls them after every ``burst_max_frames``
frames, so what is handed over at the end of a burst never waits for a pause the bus may not
make; how often a consumer acts on that is its own business (the Zenoh publisher coalesces over
``zenoh.batch_ms``). A backend that raises is reported, the bus is closed and reopened with
exponential backoff; the gateway keeps running. A bus that cannot be opened at start is retried
the same way (only an interface name python-can does not know is fatal).

A lost link is noticed by the reader within one wait (``RECV_WAIT_S``) whatever the interface:
the backend's receive raises (SocketCAN's ENETDOWN/ENODEV, python-can-remote's closed
WebSocket; for ``socketcand``, whose python-can bus never raises, ``bus.socketcand_bus`` does,
opened by ``bus.can_backend.open_can_bus``), or the sender finds its sends refused in a way that
means the link is gone (``LINK_LOST_ERRNOS`` at once; any other refusal but a full transmit
queue ``SEND_FAILURES_DOWN`` times in a row) and tells the reader, which takes the bus down the
same way: closed, state ``down`` through ``on_state``, reopened after the backoff. While it
waits for the next attempt the reader sleeps (woken at once by ``close``). The backoff doubles
with every attempt that brings no frame: it starts again from ``reopen_backoff_s`` once the
reopened bus delivers one (a link that opens and fails at once is not retried every second).

Bus state (``state``, mirrored in ``image.bus_states[network]``, with the reason in
``last_error``; one driver per CAN network, ``bus.network``):

=======  ===================================================================================
ok       frames flow; the controller is error active (or nothing says otherwise)
error    this gateway's frames cannot go out (``bus/controller.py``, its causes): the
         controller reported bus off or error passive (an error frame, or python-can's
         ``bus.state``), or the interface refused a frame (its transmit queue full after the
         retries, or another refusal); back to ok when every cause has cleared
down     the backend raised or is closed; the reader reopens it with backoff
=======  ===================================================================================

Threads: the reader thread (receives and dispatches) and the sender thread (every frame the
event loop sends is queued to it, so a blocking backend never blocks the loop; a frame refused
because the interface's transmit queue is full, ENOBUFS, is sent again a few times, a few ms
apart, before it is counted as a bus error). Both are supervised (``canopen_gateway.runtime.threads``); each
counts in its own counter set.

Clocks: ``mono`` and ``wall`` are injectable (tests use a fake clock); the bus clock and the
reopen backoff read only those.

Imports: python-can, bus.can_backend (open_can_bus, quiet_imports), bus.controller (its state, a
refused send's errno), config (DEFAULT_NETWORK),
image, runtime.ratelimit, runtime.threads. Nothing northbound.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from canopen_gateway.bus.can_backend import open_can_bus, quiet_imports
from canopen_gateway.bus.controller import ControllerState, send_errno, tx_queue_full
from canopen_gateway.config import DEFAULT_NETWORK
from canopen_gateway.image import ProcessImage
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.threads import ThreadRegistry

log = logging.getLogger("gateway.bus")

FATAL_OPEN_ERRORS = (can.CanInterfaceNotImplementedError,)  # unknown interface: a config error


class BusOpenFailed(Exception):
    """The bus could not be opened by a start that needs it (``BusDriver.open(must_open=True)``,
    a gateway started by ``run``): ``cause`` is what python-can's backend raised."""

    def __init__(self, cause: BaseException):
        super().__init__(str(cause))
        self.cause = cause

#: a frame the interface refuses with ENOBUFS (its transmit queue full; SocketCAN's default
#: txqueuelen is 10 frames, 1.1 ms each at 125 kbit/s) is sent again this often, this far apart
TX_RETRIES = 5
TX_RETRY_S = 0.002
#: frames between two calls of the burst listeners while frames keep coming: under 1 ms of the
#: reader's work at its 46-51 us per frame (bench/RESULTS.md, section 9)
BURST_MAX_FRAMES = 16
#: a frame stamped this far after the reader last looked at the clocks is not of this machine's
#: clock (a few frames' processing at most separate the two)
FRAME_TIME_AHEAD_S = 0.5
#: nor one stamped this long before (the reader's backlog after a stall is shorter)
FRAME_AGE_MAX_S = 5.0

#: the reader's wait for a frame between bursts: a link lost while the bus is quiet is noticed
#: within it (and the reader wakes this often when nothing comes, no more)
RECV_WAIT_S = 0.05
#: a send refused with one of these says the link itself is gone: the bus goes down at once
#: (a TCP transport closed, the interface down or unplugged); not ENOBUFS (a full queue)
LINK_LOST_ERRNOS = frozenset({errno.EPIPE, errno.ECONNRESET, errno.ECONNABORTED, errno.ENOTCONN,
                              errno.ESHUTDOWN, errno.EBADF, errno.ENETDOWN, errno.ENODEV, errno.ENXIO})
#: sends refused in a row (for another reason than a full transmit queue, nothing sent
#: between) that take the bus down: a vendor backend that gives no errno for a lost adapter
SEND_FAILURES_DOWN = 5

FrameHandler = Callable[[can.Message], None]


class BusDriver:
    """The bus, its reader thread and sending; see the module docstring for the states."""

    def __init__(
        self,
        bus_kwargs: dict[str, Any],
        image: ProcessImage,
        reopen_backoff_s: float = 1.0,
        on_state: Callable[[str, str], None] | None = None,
        *,
        reopen_backoff_max_s: float = 30.0,
        error_hold_s: float = 5.0,
        burst_max_frames: int = BURST_MAX_FRAMES,
        threads: ThreadRegistry | None = None,
        mono: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        network: str = DEFAULT_NETWORK,
        named: bool = False,
    ):
        #: its CAN network (state in ``image.bus_states``); ``named``: threads and logs name it
        self.network, self.where = network, f" (network {network})" if named else ""
        self._suffix = f"-{network}" if named else ""
        self.bus_kwargs = bus_kwargs
        self.image = image
        self.reopen_backoff_s = reopen_backoff_s
        self.reopen_backoff_max_s = max(reopen_backoff_max_s, reopen_backoff_s)
        #: whether its frames can go out (the causes of state ``error``; reader thread)
        self.controller = ControllerState(mono, error_hold_s)
        #: (state, detail) at every change, on the reader thread (on the caller's for the
        #: outcome of ``open``: a bus down from the start is said too)
        self.on_state = on_state
        self.handlers: dict[int, FrameHandler] = {}
        self.default_handler: FrameHandler | None = None
        #: called on the reader thread after a burst, when no received frame is left buffered,
        #: and after every ``burst_max_frames`` frames while frames keep coming
        self.burst_listeners: list[Callable[[], None]] = []
        self.burst_max_frames = burst_max_frames
        #: called on the reader thread with every received frame, in order (the web console's
        #: bus monitor, ``canopen_gateway.web.monitor``; the scan's ``bus.tap_bus.TapBus``); replaced
        #: as a whole by ``add_tap`` / ``remove_tap`` (one assignment); empty costs the reader
        #: one check per frame
        self.frame_taps: tuple[FrameHandler, ...] = ()
        self.bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._closing = threading.Event()  # set by close(): wakes a reopen backoff at once
        self._send_lock = threading.Lock()
        self._tx_full = False  # the last frame was refused, its queue full (sender thread)
        self._taps_lock = threading.Lock()  # writers of ``frame_taps`` only; the reader reads
        self.state = "down"
        self.last_error = ""
        self.reopen_attempts = 0  # attempts since the bus last delivered a frame
        #: (bus, reason): the sender found this bus's link gone (written by the sender thread
        #: only, one assignment; the reader takes that bus down when it is still the open one)
        self._send_lost: tuple[can.BusABC, str] | None = None
        self._send_failures = 0  # refused in a row, not for a full queue (sender thread)
        self.reopens = 0  # successful reopens since start
        self.warn = RateLimitedLog(log)
        #: (idle, wall-clock timestamp of the frame being processed): the bus clock's state,
        #: written by the reader thread only, always as one tuple (``bus_clock`` reads it on
        #: the event loop and must never see "busy" with the previous burst's timestamp)
        self.clock_state: tuple[bool, float] = (True, 0.0)
        self.threads = threads or ThreadRegistry()
        self.mono = mono
        self.wall = wall
        #: both clocks as the reader read them at the start of a burst (``frame_time`` turns a
        #: frame's wall-clock timestamp into the bus clock without reading a clock)
        self._burst = (mono(), wall())  # one assignment: the loop reads it too (``stamp``)
        self.rx_counters = image.counters.counter_set()  # reader thread only
        #: the reader's rounds (a wait that found nothing, a burst's start, a wait to reopen;
        #: reader thread only): standing still, the reader is stuck (``runtime.sd_notify``)
        self.reader_turns = 0
        self.tx_counters = image.counters.counter_set()  # sender thread only
        self._tx: queue.SimpleQueue[can.Message | None] = queue.SimpleQueue()
        self._sender: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def open(self, *, must_open: bool = False) -> None:
        """Open the bus and start the reader thread.

        An interface python-can does not know raises (a configuration error); any other
        failure leaves the bus down and the reader thread retries with backoff. With
        ``must_open`` (a start that stops when its bus cannot open) every failure raises
        ``BusOpenFailed`` and no thread starts: the bus is opened once, by the gateway itself.
        """
        try:
            # a start that must open says why in its own line: python-can's retries stay quiet
            with quiet_imports(logging.CRITICAL) if must_open else contextlib.nullcontext():
                self.bus = open_can_bus(self.bus_kwargs)
        except Exception as exc:
            if must_open:
                self._set_state("down", str(exc))
                raise BusOpenFailed(exc) from exc
            if isinstance(exc, FATAL_OPEN_ERRORS):
                raise
            log.error("CAN bus%s cannot be opened: %s; retrying with backoff", self.where, exc)
            self.bus = None
            self._set_state("down", str(exc), tell=True)  # down from the start: said all the same
        else:
            self._set_state("ok", "")
        self._running.set()
        self._closing.clear()
        self._thread = self.threads.start("can-reader" + self._suffix, self._run)
        self._sender = self.threads.start("can-sender" + self._suffix, self._send_loop)

    def close(self) -> None:
        self._running.clear()
        self._closing.set()
        self._tx.put(None)
        for t in (self._thread, self._sender):
            if t is not None:
                t.join(timeout=2.0)
        self._thread = self._sender = None
        self._shutdown_bus()
        self._set_state("down", "closed")

    def _shutdown_bus(self) -> None:
        bus, self.bus = self.bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001 - a dying backend may raise anything
                # python-can-remote's raises on a connection its server closed: mark the bus
                # shut all the same (else its finaliser tries again and warns)
                can.BusABC.shutdown(bus)

    def _set_state(self, state: str, detail: str, tell: bool = False) -> None:
        changed = tell or state != self.state
        self.state = state
        self.image.set_bus_state(self.network, state)
        if detail:
            self.last_error = detail
        if changed and self.on_state is not None:
            self.on_state(state, detail)

    def backoff_s(self, attempt: int) -> float:
        """Delay before reopen attempt ``attempt`` (1, 2, ...): doubling, capped."""
        return min(self.reopen_backoff_max_s, self.reopen_backoff_s * 2 ** max(0, attempt - 1))

    def bus_clock(self) -> float:
        """Monotonic time as far as the reader has got through the bus's frames.

        When the reader is behind (a backlog of received frames), supervision must judge
        timeouts by the time of the frames it has processed, not by the wall clock: a
        heartbeat waiting in the receive queue is not a lost node.
        """
        idle, last_frame_wall = self.clock_state  # one read of the reader's one assignment
        now = self.mono()
        if idle or not last_frame_wall:
            return now
        lag = self.wall() - last_frame_wall
        return now - lag if 0 < lag < FRAME_AGE_MAX_S else now  # a wall clock stepped: now

    @property
    def idle(self) -> bool:
        """The reader has caught up with the bus (nothing left buffered)."""
        return self.clock_state[0]

    @property
    def last_frame_wall(self) -> float:
        """Wall-clock timestamp of the last frame the reader took."""
        return self.clock_state[1]

    def frame_time(self, msg: can.Message) -> float:
        """A frame's receive time on the monotonic clock (``stamp`` of its timestamp)."""
        return self.stamp(msg.timestamp)

    def stamp(self, ts: float) -> float:
        """A frame timestamp on the monotonic clock. It is a wall clock (python-can's backends
        stamp frames on receipt; a socketcand server with its own), turned with both clocks as
        the reader read them at the start of the burst (per frame: no clock read); none, one
        from the future or older than ``FRAME_AGE_MAX_S`` (a wall clock stepped) is now."""
        if ts:
            mono, wall = self._burst
            t = mono - (wall - ts)
            # received before the reader's last look at the clocks (it looks at every burst and
            # every burst_max_frames), not long before: else not of this clock
            if -FRAME_AGE_MAX_S < t - mono < FRAME_TIME_AHEAD_S:
                return t
        return self.mono()

    # ------------------------------------------------------------------ sending
    def send(
        self, cob_id: int, data: bytes = b"", rtr: bool = False, dlc: int | None = None
    ) -> None:
        """Queue one frame for the sender thread (never blocks); raises ``can.CanError`` when
        the bus is down. A frame the backend then refuses is counted and logged."""
        if self.bus is None or self.state == "down":
            raise can.CanOperationError("CAN bus is down")
        self._tx.put(
            can.Message(
                arbitration_id=cob_id,
                data=data,
                is_extended_id=False,
                is_remote_frame=rtr,
                dlc=dlc if dlc is not None else len(data),
                check=False,
            )
        )

    def _send_loop(self) -> None:
        counters = self.tx_counters
        while True:
            msg = self._tx.get()
            if msg is None:
                if not self._running.is_set():
                    return
                continue
            bus = self.bus
            lost = self._send_lost
            if bus is None or (lost is not None and lost[0] is bus):
                counters["bus_errors"] += 1  # the link is gone: the reader is taking it down
                continue
            try:
                self._send_one(bus, msg)
            except Exception as exc:  # noqa: BLE001 - a refused frame must not end the sender
                counters["bus_errors"] += 1
                self.warn.warning("send", "CAN send failed: %s", exc)
                self._send_refused(bus, exc)
                continue
            self._send_failures = 0
            if self.controller.sending is not None:
                self.controller.sending = None  # it goes out again
            counters["frames_out"] += 1

    def _send_refused(self, bus: can.BusABC, exc: Exception) -> None:
        """Count a refused send: its frames cannot go out (state ``error``, taken by the reader
        at its next look); tell the reader when it says the link is gone."""
        code = send_errno(exc)
        if code == errno.ENOBUFS:
            self.controller.sending = f"transmit queue full: {exc}"
            return  # a full transmit queue (bus off, no ack), not a lost link
        self._send_failures += 1
        if code not in LINK_LOST_ERRNOS:
            self.controller.sending = f"send refused: {exc}"
        if code in LINK_LOST_ERRNOS or self._send_failures >= SEND_FAILURES_DOWN:
            self._send_failures = 0
            self._send_lost = (bus, f"send failed: {exc}")

    def _send_one(self, bus: can.BusABC, msg: can.Message) -> None:
        """Send one frame; one refused because the interface's transmit queue is full is sent
        again ``TX_RETRIES`` times, ``TX_RETRY_S`` apart, unless the frame before was refused
        the same way after all of its own (a bus off: the queue does not drain)."""
        retries = 0 if self._tx_full else TX_RETRIES
        while True:
            try:
                with self._send_lock:
                    bus.send(msg)
            except (can.CanOperationError, OSError) as exc:
                full = tx_queue_full(exc)
                if not full or retries == 0 or not self._running.is_set():
                    self._tx_full = full
                    raise
                retries -= 1
                self._closing.wait(TX_RETRY_S)  # the queue drains meanwhile
                continue
            self._tx_full = False
            return

    # ------------------------------------------------------------------ reading
    def _run(self) -> None:
        counters = self.rx_counters
        handlers = self.handlers
        in_burst = False  # within a burst: frames taken since the last wait
        pending = 0  # frames taken since the burst listeners were last called
        max_frames = self.burst_max_frames
        while self._running.is_set():
            bus = self.bus
            if bus is None:
                if not self._reopen():
                    continue
                bus = self.bus
                assert bus is not None
            lost = self._send_lost
            if lost is not None and lost[0] is bus:
                in_burst = False
                self._bus_lost(lost[1])
                continue
            try:
                # within a burst: only what is already buffered; between bursts: wait
                msg = bus.recv(timeout=0.0 if in_burst else RECV_WAIT_S)
            except Exception as exc:  # noqa: BLE001 - any backend failure keeps us running
                if not self._running.is_set():
                    break
                counters["bus_errors"] += 1
                in_burst = False
                self._bus_lost(f"receive failed: {exc}")
                continue
            if msg is None:
                # nothing left buffered: caught up with the bus
                self.reader_turns += 1
                self.clock_state = (True, self.clock_state[1])
                if in_burst:
                    in_burst = False
                    counters["bursts"] += 1
                if pending:
                    pending = 0
                    self._end_burst()
                self._look(bus)
                continue
            if not in_burst:
                self._sync_clocks()  # at a burst's start (and every burst_max_frames in one)
                if self.reopen_attempts:
                    self.reopen_attempts = 0  # the bus delivers: the next loss starts over
            in_burst = True
            pending += 1
            self.clock_state = (False, msg.timestamp)  # one assignment (see __init__)
            if msg.is_error_frame:
                counters["bus_errors"] += 1
                self._error_frame(msg)
                continue
            if self.state == "error":
                self.controller.on_frame()  # no error frame for the hold time: that cause ends
                self._apply_controller()
            counters["frames_in"] += 1
            taps = self.frame_taps  # one read: another thread may replace it meanwhile
            if taps:
                self._tap(taps, msg)
            # CANopen (CiA 301) uses 11-bit identifiers: a 29-bit frame is never ours
            h = None if msg.is_extended_id else handlers.get(msg.arbitration_id)
            try:
                if h is not None:
                    h(msg)
                elif self.default_handler is not None:
                    self.default_handler(msg)
            except Exception as exc:  # noqa: BLE001 - a bad frame must never stop the reader
                counters["decode_errors"] += 1
                self.warn.warning(
                    "handler", "frame 0x%03X could not be handled: %s", msg.arbitration_id, exc
                )
            if pending >= max_frames:  # frames keep coming: hand over what they brought
                pending = 0
                self._end_burst()
                self._sync_clocks()
                self._look(bus)

    def _bus_lost(self, detail: str) -> None:
        """The link is gone (receive raised, or the sender found it gone): close the bus, say
        ``down`` (``on_state``); the reader reopens it after the backoff."""
        log.error("CAN bus%s %s; reopening", self.where, detail)
        self._shutdown_bus()
        # nothing is buffered any more: the bus clock follows the monotonic clock again
        # (left "busy", it would stand still while the bus is down and no node could
        # time out; a node silent through the outage would never be found lost)
        self.clock_state = (True, self.clock_state[1])
        self._set_state("down", detail)

    def _sync_clocks(self) -> None:
        self.reader_turns += 1
        self._burst = (self.mono(), self.wall())

    def add_tap(self, tap: FrameHandler) -> None:
        """Call ``tap`` on the reader thread with every frame received from now on."""
        with self._taps_lock:  # two threads adding at once must not lose one
            self.frame_taps = (*self.frame_taps, tap)

    def remove_tap(self, tap: FrameHandler) -> None:
        """Stop calling ``tap`` (a frame being handled may still reach it once)."""
        with self._taps_lock:
            self.frame_taps = tuple(t for t in self.frame_taps if t != tap)

    def _tap(self, taps: tuple[FrameHandler, ...], msg: can.Message) -> None:
        for tap in taps:
            try:
                tap(msg)
            except Exception as exc:  # noqa: BLE001 - a tap must never stop the reader
                self.warn.warning("tap", "frame tap %r failed: %s", tap, exc)

    def _end_burst(self) -> None:
        for listener in self.burst_listeners:
            try:
                listener()
            except Exception as exc:  # noqa: BLE001 - a listener must never stop the reader
                self.warn.warning("burst", "burst listener %r failed: %s", listener, exc)

    def _error_frame(self, msg: can.Message) -> None:
        """Controller state from an error frame (``ControllerState.on_error_frame``)."""
        if not self.controller.on_error_frame(msg):
            data = bytes(msg.data).ljust(8, b"\0").hex(" ")
            self.warn.warning("error_frame", "CAN error frame 0x%X data %s", msg.arbitration_id, data)
        self._apply_controller()

    def _look(self, bus: can.BusABC) -> None:
        """Between bursts: the sender's refusals and python-can's bus state."""
        self.controller.look(bus)
        self._apply_controller()

    def _apply_controller(self) -> None:
        """State ``error`` while a cause holds, ``ok`` when none does (never over ``down``)."""
        if self.state == "down":
            return
        what = self.controller.error
        if what is not None:
            if self.state != "error" or self.last_error != what:
                log.warning("CAN controller%s reports %s: this gateway's frames cannot go out", self.where, what)
            self._set_state("error", what)
        elif self.state == "error":
            log.info("CAN bus%s ok again: frames go out, no error reported", self.where)
            self._set_state("ok", "")

    def _reopen(self) -> bool:
        """One reopen attempt after the backoff delay; False if it failed or we are closing."""
        delay = self.backoff_s(self.reopen_attempts + 1)
        deadline = self.mono() + delay
        while self._running.is_set() and self.mono() < deadline:
            # woken at once by close(); the deadline is judged on the injectable clock
            self._closing.wait(min(0.05, max(0.0, deadline - self.mono())))
            self.reader_turns += 1
        if not self._running.is_set():
            return False
        self.reopen_attempts += 1
        try:
            self.bus = open_can_bus(self.bus_kwargs)
        except Exception as exc:  # noqa: BLE001
            self.warn.warning(
                "reopen",
                "CAN bus%s reopen failed: %s; next attempt in %.1f s", self.where, exc,
                self.backoff_s(self.reopen_attempts + 1),
            )
            self._set_state("down", f"reopen failed: {exc}")
            return False
        self.reopens += 1
        self.controller.reset()
        log.info("CAN bus%s reopened", self.where)
        self._set_state("ok", "")
        return True
