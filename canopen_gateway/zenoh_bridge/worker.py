"""The Zenoh queries' own worker: a bounded queue, round robin between the querying sessions,
answers produced a reply at a time that give way. The PLC comes first.

Why: answered on the event loop, a burst of 500 wildcard gets held a PLC's Modbus answers for
over a second (docs/modbus.md, "What a burst costs"). Here no query runs on the event loop:

* ``submit`` (any thread: zenoh's callback) queues a job in its session's *lane*, or refuses it
  when ``queue_max`` jobs are waiting or running in all lanes, or ``lane_max`` in that lane:
  the caller answers ``busy`` at once (never silence, never an unbounded queue). A lane is the
  querying session when the query says who it is (``query.source_info``, filled in by a client
  that passes ``source_info=`` to ``get``), else one lane for every anonymous query: zenoh
  1.10 tells a queryable nothing else of the querier. The caller may give long answers (the
  history of a time range) a lane of their own, beside the short ones of the same session,
  and more units per turn (``submit``'s ``per_turn``).
* ``step`` (the worker thread, or a test: a controlled executor) takes one *turn*: the next
  lane in round robin advances its current answer by up to ``per_turn`` units (a unit is one
  reply), then the lane goes to the back of the round. A long answer (a wildcard over every
  node, thousands of history samples) is a lazy iterator and never held whole: it gives way to
  the other lanes between turns, and to the event loop (the Modbus server) after every turn:
  the thread sleeps as long as the turn took (``give_way``: at least ``GIVE_WAY_MIN_S``, at most
  ``GIVE_WAY_MAX_S``), so the queries take at most about half of the interpreter lock and a
  Modbus request waits for one turn at most, not for an answer, let alone a burst of them. A
  ``time.sleep(0)`` would not do: the thread that lets the lock go takes it back before the
  waiting one runs, which then waits the interpreter's 5 ms switch interval, at every one of
  the few times a Modbus answer needs the lock.
* A job is an iterator: ``start(item)`` makes it (on this thread), each ``next`` does one
  unit of work; its own ``finally`` finalises the query (stopping the worker closes the
  iterators that are left). An exception that escapes a job is logged (rate-limited) and
  that job dropped; the thread goes on.

Figures (read by any thread, written here under the lock): ``answered`` (jobs that ran to
their end), ``busy`` (refused at ``submit``), ``depth`` (jobs waiting or running), and
``retry_after_s`` (when a refused client should ask again: the depth times the mean job time).

Imports: runtime.ratelimit, runtime.threads, the standard library.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.threads import ThreadRegistry

log = logging.getLogger("gateway.zenoh")

T = TypeVar("T")

#: jobs waiting or running, all lanes together: past it, ``busy``
QUEUE_MAX = 400
#: jobs of one lane (one querying session, or every anonymous query together)
LANE_MAX = 200
#: replies of one answer per turn, before the next lane and the event loop get their turn
PER_TURN = 4
#: the pause after a turn: as long as the turn took, within these bounds (seconds)
GIVE_WAY_MIN_S = 0.0002
GIVE_WAY_MAX_S = 0.005
#: the retry hint's bounds, seconds
RETRY_MIN_S = 0.05
RETRY_MAX_S = 10.0
ANONYMOUS = "anonymous"


def give_way(turn_s: float) -> None:
    """Let the interpreter lock go for as long as the turn held it: a thread waiting for it
    (the event loop, with a Modbus request in hand) takes it now, not after the 5 ms switch
    interval."""
    time.sleep(min(GIVE_WAY_MAX_S, max(GIVE_WAY_MIN_S, turn_s)))


@dataclass
class _Lane(Generic[T]):
    waiting: deque[T] = field(default_factory=deque)
    current: Iterator[Any] | None = None
    started: float = 0.0
    per_turn: int = PER_TURN


class QueryWorker(Generic[T]):
    """See the module docstring. ``start`` turns an item into its job (an iterator of units)."""

    def __init__(
        self,
        start: Callable[[T], Iterator[Any]],
        *,
        queue_max: int = QUEUE_MAX,
        lane_max: int = LANE_MAX,
        per_turn: int = PER_TURN,
        clock: Callable[[], float] = time.monotonic,
        yield_fn: Callable[[float], None] = give_way,
    ) -> None:
        self._start = start
        self.queue_max = queue_max
        self.lane_max = lane_max
        self.per_turn = per_turn
        self.clock = clock
        self._give_way = yield_fn
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._lanes: dict[Hashable, _Lane[T]] = {}
        self._round: deque[Hashable] = deque()  # lanes with work, in turn order
        self._depth = 0
        self._stopping = False
        self._thread: threading.Thread | None = None
        self.answered = 0
        self.busy = 0
        self.failed = 0
        self._job_s = 0.005  # mean time of a job, first guess
        self._errlog = RateLimitedLog(log, 10.0)

    # ------------------------------------------------------------------ any thread
    @property
    def depth(self) -> int:
        """Jobs waiting or running."""
        return self._depth

    def retry_after_s(self) -> float:
        """When a refused client should ask again: the queue's depth times the mean job."""
        return min(RETRY_MAX_S, max(RETRY_MIN_S, self._depth * self._job_s))

    def submit(self, lane: Hashable, item: T, per_turn: int | None = None) -> bool:
        """Queue ``item`` in ``lane`` (``per_turn``: its units per turn, when the lane is new;
        default ``per_turn``); False (counted in ``busy``): full, answer ``busy``."""
        with self._lock:
            ln = self._lanes.get(lane)
            in_lane = 0 if ln is None else len(ln.waiting) + (ln.current is not None)
            if self._stopping or self._depth >= self.queue_max or in_lane >= self.lane_max:
                self.busy += 1
                return False
            if ln is None:
                ln = self._lanes[lane] = _Lane(per_turn=per_turn or self.per_turn)
                self._round.append(lane)
            ln.waiting.append(item)
            self._depth += 1
            self._wake.notify()
        return True

    # ------------------------------------------------------------------ the worker's thread
    def step(self) -> bool:
        """One turn (see the module docstring); False when there was nothing to do."""
        with self._lock:
            if not self._round:
                return False
            lane = self._round.popleft()
            ln = self._lanes[lane]
            item = None
            if ln.current is None:
                item = ln.waiting.popleft()
        job = ln.current
        try:
            if item is not None:
                ln.started = self.clock()
                job = ln.current = self._start(item)
            # (job is never None here: a lane in the round has a job or a waiting item)
            ended = job is None or self._advance(job, ln.per_turn)
            ok = job is not None
        except Exception as exc:  # noqa: BLE001 - logged, the job dropped, the thread goes on
            self.failed += 1
            self._errlog.warning(("job", type(exc).__name__), "a Zenoh query failed: %r", exc)
            ended, ok = True, False
        with self._lock:
            if ended:
                if ok:
                    self.answered += 1
                    self._job_s += (self.clock() - ln.started - self._job_s) / 8.0
                ln.current = None
                self._depth -= 1
            if ln.current is not None or ln.waiting:
                self._round.append(lane)
            else:
                del self._lanes[lane]
        return True

    def _advance(self, job: Iterator[Any], per_turn: int) -> bool:
        """Up to ``per_turn`` units of the job; True when it ended (an exception it raises
        goes to ``step``)."""
        try:
            for _ in range(per_turn):
                next(job)
        except StopIteration:
            return True
        return False

    def run(self) -> None:
        """The thread's loop: a turn, give way, again; sleep while there is nothing to do."""
        while True:
            with self._lock:
                while not self._round and not self._stopping:
                    self._wake.wait()
                if self._stopping:
                    return
            t0 = time.perf_counter()
            self.step()
            self._give_way(time.perf_counter() - t0)

    def start_thread(self, threads: ThreadRegistry, name: str = "zenoh-queries") -> None:
        with self._lock:
            self._stopping = False
        self._thread = threads.start(name, self.run)

    def stop(self) -> None:
        """Stop the thread (``submit`` refuses from now on); ``drain`` then empties the queue."""
        with self._lock:
            self._stopping = True
            self._wake.notify_all()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._thread = None

    def drain(self) -> list[T]:
        """After ``stop``: close the running jobs and return the items never started."""
        with self._lock:
            lanes, self._lanes = self._lanes, {}
            self._round.clear()
            self._depth = 0
        left: list[T] = []
        for ln in lanes.values():
            close = getattr(ln.current, "close", None)
            if close is not None:
                close()
            left.extend(ln.waiting)
        return left
