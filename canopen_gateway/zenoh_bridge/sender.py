"""The Zenoh bridge's publishing threads: ``zenoh-publish`` puts the values, ``zenoh-events``
the node state and EMCY events. Both are a ``ZenohSender``.

Why values have a thread of their own: a Zenoh ``put`` releases the interpreter lock while
Zenoh queues the sample (measured: 1.1 us alone, about 2 ms when another Python thread is busy,
which then holds the lock). On the CAN reader every put was a chance for the event loop to
take the lock and for the reader to wait for it back: frame -> Modbus latency grew with the
number of samples. So the reader only marks what changed and wakes ``zenoh-publish`` once per
burst; the thread takes the marks and publishes the latest values (``_ValueBatch.flush``), and
while it waits for the lock the reader and the event loop go on.

Why events have another: they use congestion control BLOCK (never dropped), and a BLOCK put
waits while a subscriber's link is congested; on the values' thread that would hold every
subscriber's values back. Events are rare; their thread sleeps in between.

* values: ``wake_values()`` (the image's batch listener: the reader at the end of a burst and
  every few frames while frames keep coming, the event loop after values read by SDO) queues
  one flush unless one is already queued; marks made meanwhile join it or the next one, none
  is left behind (the flag is cleared before the flush takes the marks). Marks coalesce per
  signal, so a slow network costs samples, never memory: the work per flush is bounded by the
  number of signals.
* ``batch_s`` (``zenoh.batch_ms``): flushes start at least this far apart. A wake-up after a
  quiet window flushes at once; one that comes sooner waits for the window's end, and the
  marks of the window go out together. While marks keep coming a flush goes out every
  ``batch_s`` (or as fast as flushes run), whether or not the bus ever pauses. The window is
  the publisher's alone: the reader, and with it the process image (Modbus), is never held.
* events: computed on the event loop (``events.py``) and queued with ``put_event`` in order,
  with their journal ticket. Each waits for its commit at most ``EVENT_WAIT_S`` from when it
  was made (``journal_wait``), then goes out: a stalled, slow or full disk delays an event by
  200 ms at most, and the events published before their commit are counted
  (``on_unjournaled``). The publisher of its key is looked up when it is put (``pub_of``):
  while no session is open (client mode without a router) events wait in a backlog (at most
  ``BACKLOG_MAX``, the oldest dropped first and counted) and go out in order, before any newer
  one, once the session's publishers are declared (``resend``). An event whose key this
  gateway no longer publishes when its turn comes (``pub_of`` answers ``WITHHELD``: a pair's
  other member masters its node's network now) is not published, only counted (``withheld``):
  it is journaled, and it never holds back the events of the keys this gateway publishes.

Not here: ``publish: every`` samples (one per frame, put by the reader as the frame is handled)
and the housekeeping's rare puts on the event loop (quality changes no frame announces,
held-back samples whose time has come).

Started through the gateway's ``ThreadRegistry``: a thread that dies is reported and turns
/healthz not-ready. A failed put is counted and logged, and the thread goes on.

Clocks: ``clock`` and ``wait`` are injectable (tests use a fake clock); ``stop`` ends a window
being waited for at once.

Imports: runtime.threads. Never zenoh (it calls ``put`` on the publishers it is given and
makes timestamps with the function it is given), modbus/ nor bus/.
"""

from __future__ import annotations

import collections
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from canopen_gateway.runtime.threads import ThreadRegistry

log = logging.getLogger("gateway.zenoh")

_FLUSH = object()  # queue item: publish the marked values
_RESEND = object()  # queue item: the session's publishers are there, publish the backlog
_STOP = None  # queue item: end the thread
#: an event waits for its commit at most this long (seconds) before it is published anyway
EVENT_WAIT_S = 0.2
#: events kept while no session is open, at most
BACKLOG_MAX = 10_000
#: ``pub_of``'s answer for a key this gateway does not publish (a pair's other member does)
WITHHELD = object()


class ZenohSender:
    """Puts on its own thread, in the order queued: value flushes (``flush`` given) and
    events."""

    def __init__(
        self,
        threads: ThreadRegistry,
        name: str,
        flush: Callable[[], None] | None = None,
        *,
        batch_s: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        wait: Callable[[float], Any] | None = None,
        pub_of: Callable[[str], Any] | None = None,
        timestamp: Callable[[int], Any] | None = None,
    ) -> None:
        self.threads = threads
        self.name = name
        self.flush = flush
        #: flushes start at least this far apart (``clock`` seconds; 0: at every wake-up)
        self.batch_s = batch_s
        self.clock = clock
        self._stopping = threading.Event()
        #: waits up to the given seconds for a window's end; returns early when stopping
        self.wait: Callable[[float], Any] = wait if wait is not None else self._stopping.wait
        self.queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.thread: threading.Thread | None = None
        self._flush_queued = False
        self._last_flush_s = float("-inf")  # ``clock`` time the last flush started
        self.sent = 0  # events put
        self.failed = 0  # events whose put failed
        self.withheld = 0  # events of keys this gateway no longer publishes (``WITHHELD``)
        self.flushes = 0  # value flushes run
        #: events: the publisher of a key (None: no session; ``WITHHELD``), the timestamp of
        #: a stamp (ns)
        self.pub_of: Callable[[str], Any] = pub_of or (lambda key: None)
        self.timestamp: Callable[[int], Any] = timestamp or (lambda ns: None)
        #: events: wait for a journal ticket (ticket, timeout) -> committed in time; and the
        #: count of those published before it
        self.journal_wait: Callable[[int, float], bool] | None = None
        self.on_unjournaled: Callable[[], None] = lambda: None
        self.backlog: collections.deque[tuple[str, bytes, int]] = collections.deque()
        self.backlog_dropped = 0

    def start(self) -> None:
        self._stopping.clear()
        self.thread = self.threads.start(self.name, self._run)

    def wake_values(self) -> None:
        """The end of a writer's batch: publish the marked values on this thread (one queued
        flush at a time; any thread)."""
        if not self._flush_queued:
            self._flush_queued = True
            self.queue.put(_FLUSH)

    def put_event(self, key: str, payload: bytes, stamp_ns: int, ticket: int = 0) -> None:
        """An event (any thread, in order): published once its journal ``ticket`` is committed
        (0: none) or ``EVENT_WAIT_S`` after now, whichever comes first."""
        self.queue.put((key, payload, stamp_ns, ticket, self.clock() + EVENT_WAIT_S))

    def resend(self) -> None:
        """The session's publishers are declared: the events kept meanwhile go out."""
        self.queue.put(_RESEND)

    def stop(self, timeout_s: float = 2.0) -> None:
        """Publish what is queued (and marked), then end the thread."""
        if self.thread is None:
            return
        self._stopping.set()  # a window being waited for ends now
        if self.flush is not None:
            self.queue.put(_FLUSH)
        self.queue.put(_STOP)
        self.thread.join(timeout_s)
        self.thread = None

    def _run(self) -> None:
        while True:
            item = self.queue.get()
            if item is _STOP:
                return
            if item is _FLUSH:
                early_s = self._last_flush_s + self.batch_s - self.clock()
                if early_s > 0 and not self._stopping.is_set():
                    self.wait(early_s)  # the window's marks go out together, at its end
                self._last_flush_s = self.clock()
                self._flush_queued = False  # before the marks are taken: none is left behind
                self.flushes += 1
                if self.flush is not None:
                    self.flush()  # catches and logs what a value's publication raises
                continue
            if item is _RESEND:
                self._publish_backlog()
                continue
            key, payload, ns, ticket, deadline = item
            wait = self.journal_wait
            if ticket and wait is not None and not wait(ticket, max(0.0, deadline - self.clock())):
                self.on_unjournaled()  # the disk is slow: published before its commit
            self._publish_backlog()
            if not self._put(key, payload, ns):
                self._keep(key, payload, ns)

    def _put(self, key: str, payload: bytes, ns: int) -> bool:
        """Put one event; False when its key has no publisher (no session)."""
        try:
            pub = self.pub_of(key)
            if pub is None:
                return False
            if pub is WITHHELD:
                self.withheld += 1
                return True
            pub.put(payload, timestamp=self.timestamp(ns))
            self.sent += 1
        except Exception as exc:  # noqa: BLE001 - one failed put must not stop the events
            self.failed += 1
            log.warning("zenoh event publication failed: %r", exc)
        return True

    def _keep(self, key: str, payload: bytes, ns: int) -> None:
        if len(self.backlog) >= BACKLOG_MAX:
            self.backlog.popleft()
            self.backlog_dropped += 1
        self.backlog.append((key, payload, ns))

    def _publish_backlog(self) -> None:
        while self.backlog:
            key, payload, ns = self.backlog[0]
            if not self._put(key, payload, ns):
                return
            self.backlog.popleft()
