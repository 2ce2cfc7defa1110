"""Live updates of the web console: from the process image to each browser, coalesced.

Rule 1: the console's one hand-off from the CAN reader thread to the event loop is
``LiveHub._on_values``. The reader adds the names of the updated signals to a pending dict
under a lock and calls ``loop.call_soon_threadsafe`` only when no hand-off is armed; the loop
takes the whole batch and stays armed for ``HANDOFF_PERIOD_S``, taking what came meanwhile, and
disarms when a period brought nothing. So a bus at 10,000 frames/s costs the reader a set update
per frame and the loop at most ``1 / HANDOFF_PERIOD_S`` wake-ups a second. Nobody watching a
node costs the reader one set lookup per frame.

Rule 2: a client is a set of dirty keys, never a queue of values. What is sent is the image's
current value when the client's turn comes, at most ``MAX_UPDATES_PER_S`` times a second, and a
full refresh every ``FULL_REFRESH_S`` (ages, rates). A client whose socket does not drain (more
than ``MAX_BUFFERED_BYTES`` waiting in the transport) is skipped, its dirty set waiting (bounded
by the number of signals and nodes), and dropped after ``SLOW_CLIENT_LIMIT_S``. Nothing the
gateway does ever waits for a browser. ``stream_sse`` is that pump, the bus monitor's pages' too.

Rule 3: everything here runs on the event loop, except ``_on_values`` (the reader thread).
Health listeners are called on the event loop by the image's writer.

The PLC comes first: with ``turns`` (``turns.LoopTurns``), each update is rendered in its turn
on the event loop, one piece of northbound work per loop iteration.

Imports: image, http.messages (what a stream writes to), runtime.turns (the rendering is given as a function by the console).
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from collections.abc import Callable
from typing import Any

from canopen_gateway.http.messages import StreamOut
from canopen_gateway.image import NodeImage, ProcessImage
from canopen_gateway.runtime.turns import LoopTurns

log = logging.getLogger("gateway.web")

MAX_UPDATES_PER_S = 10
MIN_SEND_INTERVAL_S = 1.0 / MAX_UPDATES_PER_S
FULL_REFRESH_S = 1.0
HANDOFF_PERIOD_S = 0.05
MAX_BUFFERED_BYTES = 256 * 1024
SLOW_CLIENT_LIMIT_S = 30.0
MAX_CLIENTS = 64
#: EventSource reconnects after this many ms when the stream ends (gateway restart)
RETRY_MS = 2000


class Handoff:
    """The console's hand-off to the event loop, coalesced (Rule 1; the bus monitor's too).

    The producer adds to its pending batch under ``lock``, calls ``arm()`` there, and when that
    says so calls ``wake()`` after the lock: one ``call_soon_threadsafe`` for a whole flow. On
    the loop, ``take`` (under the lock) empties the batch and returns it; ``deliver`` gets it
    (without the lock); the hand-off stays armed ``period_s`` and takes again, and disarms when
    a period brought nothing."""

    def __init__(
        self,
        take: Callable[[], Any],
        deliver: Callable[[Any], None],
        period_s: float = HANDOFF_PERIOD_S,
    ):
        self.lock = threading.Lock()
        self._take_batch = take
        self._deliver = deliver
        self.period_s = period_s
        self.armed = False  # under the lock
        self.loop: asyncio.AbstractEventLoop | None = None
        self.handoffs = 0  # call_soon_threadsafe calls made by the producer
        self.batches = 0  # batches taken on the loop

    def arm(self) -> bool:
        """Under ``lock``, after adding to the batch: True when the caller must ``wake()``."""
        if self.armed:
            return False
        self.armed = True
        return True

    def wake(self) -> None:
        """After ``arm()`` said so, outside the lock: have the loop take the batch."""
        loop = self.loop
        if loop is None:
            return
        self.handoffs += 1
        try:
            loop.call_soon_threadsafe(self.take)
        except RuntimeError:  # the loop is closed: the gateway is stopping
            pass

    def take(self) -> None:
        """On the loop: take the pending batch, deliver it, stay armed one period."""
        with self.lock:
            batch = self._take_batch()
            if not batch:
                self.armed = False
                return
        self.batches += 1
        self._deliver(batch)
        loop = self.loop
        if loop is not None:
            loop.call_later(self.period_s, self.take)
        else:
            with self.lock:
                self.armed = False


class Subscriber:
    """One browser's stream: which node it watches (None: the overview and nodes table) and
    what changed since its last update."""

    __slots__ = ("node", "dirty_values", "dirty_health", "wake", "sent", "skipped",
                 "trend_seq", "event_seq")  # fmt: skip

    def __init__(self, node: str | None):
        self.node = node
        self.dirty_values: set[str] = set()
        self.dirty_health: set[str] = set()
        self.wake = asyncio.Event()
        self.sent = 0  # updates written
        self.skipped = 0  # turns skipped because the socket did not drain
        self.trend_seq = 0  # the last trend sample sent (node pages)
        self.event_seq = 0  # the last event of the event log sent (overview stream)


#: render(subscriber, full) -> [(event name, JSON-able data)]; clears what it has rendered
Render = Callable[[Subscriber, bool], list[tuple[str, Any]]]


def sse(event: str, data: Any) -> bytes:
    """One server-sent event (HTML Living Standard 9.2): ``event:`` and one ``data:`` line."""
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'), default=str)}\n\n".encode()


class TooManyClients(Exception):
    pass


class LiveHub:
    """Subscribers and the hand-off from the image's listeners (see the module docstring)."""

    def __init__(self, image: ProcessImage, *, max_clients: int = MAX_CLIENTS):
        self.image = image
        self.max_clients = max_clients
        self.subscribers: set[Subscriber] = set()
        self._watched: frozenset[str] = frozenset()  # read by the reader thread
        self._pending: dict[str, set[str]] = {}  # under the hand-off's lock
        self.handoff = Handoff(self._swap, self._deliver)

    @property
    def handoffs(self) -> int:
        """``call_soon_threadsafe`` calls made by the reader thread."""
        return self.handoff.handoffs

    # ------------------------------------------------------------------ lifecycle
    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self.handoff.loop = loop
        self.image.value_listeners.append(self._on_values)
        self.image.health_listeners.append(self._on_health)

    def detach(self) -> None:
        if self._on_values in self.image.value_listeners:
            self.image.value_listeners.remove(self._on_values)
        if self._on_health in self.image.health_listeners:
            self.image.health_listeners.remove(self._on_health)
        self._watched = frozenset()
        self.handoff.loop = None

    def subscribe(self, node: str | None) -> Subscriber:
        if len(self.subscribers) >= self.max_clients:
            raise TooManyClients(f"at most {self.max_clients} live pages at a time")
        sub = Subscriber(node)
        self.subscribers.add(sub)
        self._rewatch()
        return sub

    def unsubscribe(self, sub: Subscriber) -> None:
        self.subscribers.discard(sub)
        self._rewatch()

    def _rewatch(self) -> None:
        # one assignment: the reader thread sees the old set or the new one
        self._watched = frozenset(s.node for s in self.subscribers if s.node is not None)

    # ------------------------------------------------------------------ hand-off
    def _on_values(self, node: NodeImage, names: tuple[str, ...], ts: float) -> None:
        """Value listener: CAN reader thread (or the loop for SDO-read values)."""
        if node.name not in self._watched:
            return
        h = self.handoff
        with h.lock:
            pending = self._pending.get(node.name)
            if pending is None:
                self._pending[node.name] = set(names)
            else:
                pending.update(names)
            if not h.arm():
                return
        h.wake()

    def _swap(self) -> dict[str, set[str]]:
        """Under the hand-off's lock, on the loop: the pending batch, emptied."""
        batch, self._pending = self._pending, {}
        return batch

    def _deliver(self, batch: dict[str, set[str]]) -> None:
        """On the loop: mark the batch's signals dirty for the pages that watch their node."""
        for sub in self.subscribers:
            names = batch.get(sub.node) if sub.node is not None else None
            if names:
                sub.dirty_values |= names
                sub.wake.set()

    def _on_health(self, node: NodeImage, what: str) -> None:
        """Health listener: on the event loop."""
        for sub in self.subscribers:
            if sub.node is None or sub.node == node.name:
                sub.dirty_health.add(node.name)
                sub.wake.set()

    # ------------------------------------------------------------------ one client
    async def pump(
        self,
        sub: Subscriber,
        render: Render,
        out: StreamOut,
        *,
        slow_limit_s: float = SLOW_CLIENT_LIMIT_S,
        max_buffered: int = MAX_BUFFERED_BYTES,
        turns: LoopTurns | None = None,
    ) -> None:
        """Write ``sub``'s updates to ``out`` until the client goes away (or is too slow):
        what changed, at most ``MAX_UPDATES_PER_S`` times a second, everything every
        ``FULL_REFRESH_S``."""
        last_full = -FULL_REFRESH_S

        def turn(now: float) -> bytes:
            nonlocal last_full
            full = now - last_full >= FULL_REFRESH_S
            events = render(sub, full)
            if full:
                last_full = now
            if not events:
                return b""
            sub.sent += 1
            return b"".join(sse(name, data) for name, data in events)

        def skip() -> None:
            sub.skipped += 1

        try:
            await stream_sse(
                out,
                sub.wake,
                turn,
                lambda: last_full + FULL_REFRESH_S,
                interval_s=MIN_SEND_INTERVAL_S,
                who="web console client",
                on_skip=skip,
                slow_limit_s=slow_limit_s,
                max_buffered=max_buffered,
                turns=turns,
            )
        finally:
            self.unsubscribe(sub)


async def stream_sse(
    out: StreamOut,
    wake: asyncio.Event,
    turn: Callable[[float], bytes],
    due: Callable[[], float],
    *,
    interval_s: float,
    who: str,
    first: bytes = b"",
    on_skip: Callable[[], None] | None = None,
    slow_limit_s: float = SLOW_CLIENT_LIMIT_S,
    max_buffered: int = MAX_BUFFERED_BYTES,
    turns: LoopTurns | None = None,
) -> None:
    """The one server-sent-event pump of the console (the live pages and the bus monitor, Rule 2).

    Writes the ``retry:`` line and ``first``, then, until the browser goes away (``out.gone``:
    it sends nothing) or its connection closes, one ``turn(now)`` (loop time; the bytes to write,
    ``b""`` for nothing) when ``wake`` is set or the loop time ``due()`` has come, at most one
    write every ``interval_s``: what comes meanwhile joins the next write. A turn whose socket
    holds more than ``max_buffered`` bytes is skipped (``on_skip``), ``wake`` left set; after
    ``slow_limit_s`` of skipped turns the client (``who``, in the log) is dropped. With
    ``turns``, each ``turn`` waits for its turn on the event loop (the PLC first)."""
    loop = asyncio.get_running_loop()
    gone = out.gone
    last_send = float("-inf")
    slow_since: float | None = None
    out.write(f"retry: {RETRY_MS}\n\n".encode() + first)
    while not gone.done() and not out.closing():
        wait_s = max(0.0, due() - loop.time())
        if not wake.is_set() and wait_s > 0:
            woken = asyncio.ensure_future(wake.wait())
            await asyncio.wait({woken, gone}, timeout=wait_s, return_when="FIRST_COMPLETED")
            woken.cancel()
            if gone.done():
                break
        gap = last_send + interval_s - loop.time()
        if gap > 0:
            await asyncio.sleep(gap)
        now = loop.time()
        if out.buffered() > max_buffered:
            if on_skip is not None:
                on_skip()
            if slow_since is None:
                slow_since = now
            elif now - slow_since > slow_limit_s:
                log.info("%s dropped: it has not read for %.0f s", who, slow_limit_s)
                break
            last_send = now  # try again one interval later
            continue
        slow_since = None
        if turns is not None:
            await turns.turn(bounded=False)
            if gone.done() or out.closing():
                break
        wake.clear()
        data = turn(now)
        if data:
            out.write(data)
            last_send = now
