"""The CAN bus driver: owns the python-can bus, the reader thread and sending.

A reader thread receives frames and dispatches them by COB-ID through a dict:
process data (TPDOs) is decoded and written into the process image right on this thread (the hot
path: no event-loop hop, no logging per frame); everything else (heartbeat, EMCY, SDO, LSS) is
handed to its handler, which for control traffic forwards to the event loop. A backend that
raises is reported, the bus is closed and reopened with backoff; the gateway keeps running.

Imports: python-can, image (for counters). Nothing northbound.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from gateway.image import ProcessImage

log = logging.getLogger("gateway.bus")

FrameHandler = Callable[[can.Message], None]


class RateLimitedLog:
    """Log a recurring problem at most once per ``period_s`` per key, with a count."""

    def __init__(self, logger: logging.Logger, period_s: float = 10.0):
        self.logger = logger
        self.period_s = period_s
        self._last: dict[Any, float] = {}
        self._suppressed: dict[Any, int] = {}

    def warning(self, key: Any, msg: str, *args: Any) -> None:
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.period_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        n = self._suppressed.pop(key, 0)
        self._last[key] = now
        if n:
            self.logger.warning(msg + " (%d more suppressed)", *args, n)
        else:
            self.logger.warning(msg, *args)


class BusDriver:
    def __init__(
        self,
        bus_kwargs: dict[str, Any],
        image: ProcessImage,
        reopen_backoff_s: float = 1.0,
        on_state: Callable[[str, str], None] | None = None,
    ):
        self.bus_kwargs = bus_kwargs
        self.image = image
        self.reopen_backoff_s = reopen_backoff_s
        self.on_state = on_state  # (state, detail), called on the reader thread
        self.handlers: dict[int, FrameHandler] = {}
        self.default_handler: FrameHandler | None = None
        self.bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None
        self._running = threading.Event()
        self._send_lock = threading.Lock()
        self.state = "down"
        self.last_error = ""
        self.warn = RateLimitedLog(log)

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Open the bus once (raises if the backend refuses) and start the reader thread."""
        self.bus = can.Bus(**self.bus_kwargs)
        self._set_state("ok", "")
        self._running.set()
        self._thread = threading.Thread(target=self._run, name="can-reader", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._running.clear()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._shutdown_bus()
        self._set_state("down", "closed")

    def _shutdown_bus(self) -> None:
        bus, self.bus = self.bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001 - a dying backend may raise anything
                pass

    def _set_state(self, state: str, detail: str) -> None:
        self.state = state
        self.image.bus_state = state
        if detail:
            self.last_error = detail
        if self.on_state is not None:
            self.on_state(state, detail)

    # ------------------------------------------------------------------ sending
    def send(self, cob_id: int, data: bytes = b"", rtr: bool = False, dlc: int | None = None) -> None:
        """Send one frame; raises ``can.CanError`` when the bus is down."""
        bus = self.bus
        if bus is None or self.state == "down":
            raise can.CanOperationError("CAN bus is down")
        msg = can.Message(
            arbitration_id=cob_id,
            data=data,
            is_extended_id=False,
            is_remote_frame=rtr,
            dlc=dlc if dlc is not None else len(data),
        )
        try:
            with self._send_lock:
                bus.send(msg)
        except can.CanError as exc:
            self.image.counters["bus_errors"] += 1
            self.warn.warning("send", "CAN send failed: %s", exc)
            raise
        self.image.counters["frames_out"] += 1

    # ------------------------------------------------------------------ reading
    def _run(self) -> None:
        counters = self.image.counters
        handlers = self.handlers
        while self._running.is_set():
            bus = self.bus
            if bus is None:
                if not self._reopen():
                    continue
                bus = self.bus
                assert bus is not None
            try:
                msg = bus.recv(timeout=0.05)
            except Exception as exc:  # noqa: BLE001 - any backend failure keeps us running
                counters["bus_errors"] += 1
                log.error("CAN bus receive failed: %s; reopening", exc)
                self._shutdown_bus()
                self._set_state("down", str(exc))
                continue
            if msg is None:
                continue
            if msg.is_error_frame:
                counters["bus_errors"] += 1
                self._error_frame(msg)
                continue
            counters["frames_in"] += 1
            h = handlers.get(msg.arbitration_id)
            try:
                if h is not None:
                    h(msg)
                elif self.default_handler is not None:
                    self.default_handler(msg)
            except Exception as exc:  # noqa: BLE001 - a bad frame must never stop the reader
                counters["decode_errors"] += 1
                self.warn.warning(
                    ("handler", msg.arbitration_id),
                    "frame 0x%03X could not be handled: %s",
                    msg.arbitration_id,
                    exc,
                )

    def _error_frame(self, msg: can.Message) -> None:
        # DS-301 / CiA 102: error passive and bus off are reported in error frames' data
        data = bytes(msg.data)
        if msg.arbitration_id & 0x40 or (len(data) > 1 and data[1] & 0x30):
            self._set_state("error", "error passive / bus off reported by the controller")

    def _reopen(self) -> bool:
        deadline = time.monotonic() + self.reopen_backoff_s
        while self._running.is_set() and time.monotonic() < deadline:
            time.sleep(0.05)
        if not self._running.is_set():
            return False
        try:
            self.bus = can.Bus(**self.bus_kwargs)
        except Exception as exc:  # noqa: BLE001
            self.warn.warning("reopen", "CAN bus reopen failed: %s", exc)
            self._set_state("down", str(exc))
            return False
        log.info("CAN bus reopened")
        self._set_state("ok", "")
        return True
