"""Turns on the event loop for the northbound clients that are not the PLC: the web console's
API, its live pages and the CiA 309-3 ASCII clients. The PLC comes first.

The Modbus server answers a PLC on the event loop. asyncio runs, in each iteration, every
callback that was ready when the iteration began, then polls its sockets again: 200 console
requests that arrive together would all be rendered before the PLC's next request is even
read (a PLC waited 0.9 s behind them, bench ``plc-first``). A client takes a *turn* before
its piece of work (rendering an API answer, a live page's update, an ASCII command): at most
``per_iteration`` pieces run per loop iteration, and the loop polls its sockets, the PLC's
included, between two of them. So a Modbus request waits for one piece at most, never for a
burst.

Bounded: at most ``waiting_max`` clients wait for a turn; past that ``turn`` answers False at
once and the caller refuses the request (the console: 503 with ``Retry-After``; an ASCII
client: its error line), counted in ``refused``. A waiter that goes away (its task cancelled)
gives its turn up.

Runs on the event loop only (no lock). Imports: the standard library only.
"""

from __future__ import annotations

import asyncio
from collections import deque

#: pieces of northbound work per loop iteration
PER_ITERATION = 1
#: and at least this long between two turns (seconds): a burst is spread out in time too, so
#: the other processes of a small machine (the PLC's own, on a shared one) get a processor
MIN_GAP_S = 0.001
#: clients waiting for a turn: past it, refused
WAITING_MAX = 256
#: what a refused client is told: ask again after this many seconds
RETRY_AFTER_S = 1
#: connections a northbound server (HTTP, ASCII) accepts per loop iteration and leaves waiting
#: in the kernel: a burst of clients is let in a few at a time, and the loop polls its other
#: sockets (a PLC's) in between; a client whose connection is not taken yet tries again (TCP)
ACCEPT_BACKLOG = 16


class LoopTurns:
    """See the module docstring."""

    def __init__(
        self,
        per_iteration: int = PER_ITERATION,
        waiting_max: int = WAITING_MAX,
        min_gap_s: float = MIN_GAP_S,
    ):
        self.per_iteration = per_iteration
        self.waiting_max = waiting_max
        self.min_gap_s = min_gap_s
        self._last = float("-inf")  # loop time of the last turn given
        self._used = 0
        self._armed = False
        self._waiters: deque[asyncio.Future[None]] = deque()
        self.granted = 0
        self.refused = 0

    @property
    def waiting(self) -> int:
        return len(self._waiters)

    async def turn(self, bounded: bool = True) -> bool:
        """Wait for a turn (True), or False at once when ``waiting_max`` clients wait. A
        client already bounded by its own limit (a live page: at most so many streams, each
        waiting for one turn at a time) passes ``bounded=False`` and always waits."""
        loop = asyncio.get_running_loop()
        if (
            self._used < self.per_iteration
            and not self._waiters
            and loop.time() - self._last >= self.min_gap_s
        ):
            self._used += 1
            self.granted += 1
            self._last = loop.time()
            self._arm(loop)
            return True
        if bounded and len(self._waiters) >= self.waiting_max:
            self.refused += 1
            return False
        fut: asyncio.Future[None] = loop.create_future()
        self._waiters.append(fut)
        self._arm(loop)
        await fut  # cancelled: the future is done, ``_next`` skips it
        return True

    def _arm(self, loop: asyncio.AbstractEventLoop) -> None:
        if not self._armed:
            self._armed = True
            due = self._last + self.min_gap_s
            if self._waiters and loop.time() < due:
                loop.call_at(due, self._next, loop)
            else:
                loop.call_soon(self._next, loop)

    def _next(self, loop: asyncio.AbstractEventLoop) -> None:
        """A new loop iteration (the sockets were polled since the last), and the gap since
        the last turn past: new turns."""
        self._armed = False
        self._used = 0
        if self._waiters and loop.time() - self._last < self.min_gap_s:
            self._arm(loop)
            return
        while self._waiters and self._used < self.per_iteration:
            fut = self._waiters.popleft()
            if not fut.done():
                fut.set_result(None)
                self._used += 1
                self.granted += 1
                self._last = loop.time()
        if self._used or self._waiters:
            self._arm(loop)
