"""The ``zenoh-events`` thread of the Zenoh bridge: node state and EMCY events, computed on the
event loop, are put in order on this thread (congestion control BLOCK may wait; the event
loop must not). Started through the gateway's ``ThreadRegistry``; a failed put is counted and
logged, and the thread goes on.

Imports: threads. Never zenoh (it calls ``put`` on the publishers it is given), modbus/ nor
bus/.
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Any

from gateway.threads import ThreadRegistry

log = logging.getLogger("gateway.zenoh")


class EventSender:
    """Puts events in order on its own thread (BLOCK may wait; the event loop must not)."""

    def __init__(self, threads: ThreadRegistry) -> None:
        self.threads = threads
        self.queue: queue.SimpleQueue[tuple[Any, bytes, Any] | None] = queue.SimpleQueue()
        self.thread: threading.Thread | None = None
        self.sent = 0
        self.failed = 0

    def start(self) -> None:
        self.thread = self.threads.start("zenoh-events", self._run)

    def put(self, pub: Any, payload: bytes, timestamp: Any) -> None:
        self.queue.put((pub, payload, timestamp))

    def stop(self, timeout_s: float = 2.0) -> None:
        if self.thread is None:
            return
        self.queue.put(None)
        self.thread.join(timeout_s)
        self.thread = None

    def _run(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            pub, payload, ts = item
            try:
                pub.put(payload, timestamp=ts)
                self.sent += 1
            except Exception as exc:  # noqa: BLE001 - one failed put must not stop the events
                self.failed += 1
                log.warning("zenoh event publication failed: %r", exc)
