"""The journal: one SQLite database (standard library, WAL mode) in ``journal.path``, written by
one thread (``journal-writer``), read by any thread through connections of its own.

What goes in (``Entry``): every state and EMCY event (``append``), the latest value sample of
each signal per ``values_ms`` window (``value``: a dict assignment, the writer takes the
window's latest; or ``values_from``: the writer asks a source once per window), and the audit
of every write (``append``).

Rules held here, once:

* **Never blocks a caller, never stops the live path**: ``append`` checks the entry and queues
  it (under a lock, no I/O) and returns a ticket; whoever must know it is on disk waits for its
  ticket, bounded (``wait``: the events' thread waits at most 200 ms, then publishes without
  it; ``when_done``: the audit). The queue is bounded in entries and in bytes
  (``max_pending``, ``MAX_PENDING_BYTES``): past it a new entry is dropped (counted), nothing
  of it kept.
* **Intake refuses what cannot be stored** (a ``seq`` or a time outside SQLite's integers, a
  kind it does not know, an oversized payload): counted in ``refused``, logged at most once a
  minute, never handed to the writer. The writer survives any entry and any error: a failing
  commit drops its rows (counted), a full disk trims the oldest entries and retries
  (``_recover_full``), a file found damaged while running is set aside and a fresh one
  started; a step that raises anyway is logged and the thread goes on.
* **Group commit**: the writer takes everything queued (at most ``BATCH_ROWS``), inserts it in
  one transaction (``db.commit``), marks the tickets done.
* **Bounded**: room is made in the commit that needs it (``db.make_room``: the oldest first,
  in bounded chunks) within ``max_mb`` and within what the disk has (its free space, or what a
  full disk allowed); expired entries (``keep_days``) go a chunk per step from the start on;
  the WAL is checkpointed (truncated) when it passes its bound (an eighth of the budget, 16 MB
  at most); damaged files set aside are pruned (``files.prune_aside``).
* **``seq`` is never used twice** (``files.SeqMarks``): the highest ``seq`` per key of every
  entry handed in (journaled or not) is kept in the database and beside it; ``last_seqs`` gives
  them at start. ``hlc`` is the clock of the gateway's stamps (``clock.HybridClock``), seeded
  with the newest time the journal holds: stamps never go back across restarts.
* **One writer per file** (``files.FileLock``) and damage told apart from trouble
  (``files.damage``); ``status()`` says whether it journals and, if not, why.

Imports: the standard library, journal.clock, journal.db, journal.files, journal.writer,
runtime.ratelimit, runtime.threads. Never zenoh (timestamps are taken by duck type: ``get_time_as_ntp64``,
``get_id``), nor any adapter.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from canopen_gateway.journal import db, files
from canopen_gateway.journal.clock import NANOS, NTP64_MAX, HybridClock, ns_of_ntp64
from canopen_gateway.journal.db import Row
from canopen_gateway.journal.files import FILE_NAME, SeqMarks
from canopen_gateway.journal.writer import DiskWriter, JournalCounts
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.threads import ThreadRegistry

log = logging.getLogger("gateway.journal")

KINDS = frozenset({"state", "emcy", "value", "audit"})
BATCH_ROWS = 2000  # entries per commit at most
MAX_PENDING = 50_000  # entries waiting for the writer before new ones are dropped
MAX_PENDING_BYTES = 32 << 20  # bytes of the entries waiting, likewise
MAX_ENTRY_BYTES = 1 << 20  # one entry's payload and key
MAX_WATCHERS = 10_000  # ``when_done`` callbacks waiting
LOG_PERIOD_S = 60.0  # drops and refusals are logged at most once per period
STALL_S = 1.0  # a commit waiting longer than this: the disk does not answer
FULL_SHOWN_S = 60.0  # /healthz names the full disk this long after it last was
INT64 = 1 << 63


class Entry(NamedTuple):
    """One journal entry. ``stamp``: a Zenoh timestamp (of the publication) or an NTP64 int."""

    stamp: Any
    kind: str  # state | emcy | value | audit
    key: str  # the Zenoh key it was published on (``<prefix>/audit`` for the audit)
    node: str | None
    seq: int | None
    payload: bytes | str  # as published (text is stored as its UTF-8 bytes)


def intake(e: Entry) -> db.DbRow | str:
    """The row an entry is stored as, or why it cannot be (any thread, no I/O)."""
    try:
        s = e.stamp
        if isinstance(s, int):
            t, tid = s, None
        else:
            t, tid = int(str(s.get_time_as_ntp64())), bytes(s.get_id())
        data = e.payload.encode() if isinstance(e.payload, str) else bytes(e.payload)
    except (AttributeError, TypeError, ValueError, UnicodeError) as exc:
        return f"not an entry ({exc})"
    if isinstance(t, bool) or not 0 <= t <= NTP64_MAX:
        return f"time {t!r} is not an NTP64 time"
    if e.kind not in KINDS or not isinstance(e.key, str) or not e.key:
        return f"kind {e.kind!r} / key {e.key!r} is not one the journal keeps"
    if e.node is not None and not isinstance(e.node, str):
        return f"node {e.node!r} is not a name"
    seq = e.seq
    if seq is not None and (not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < INT64):
        return f"seq {seq!r} of {e.key} is not an integer from 0 to 2**63 - 1"
    if len(data) + len(e.key) > MAX_ENTRY_BYTES:
        return f"{len(data)} bytes on {e.key}: more than {MAX_ENTRY_BYTES} in one entry"
    return (t - db.T_BIAS, e.kind, e.key, e.node, seq, data, tid)


@dataclass(eq=False)
class Journal:
    """The store (see the module docstring). ``open`` then ``start``; ``stop`` commits what
    waits (values of the current window too) and closes."""

    directory: Path
    max_mb: float = 256
    values_ms: int = 1000
    keep_days: float = 30
    sync: str = "normal"
    clock: Callable[[], float] = time.time
    max_pending: int = MAX_PENDING
    max_pending_bytes: int = MAX_PENDING_BYTES
    counts: JournalCounts = field(default_factory=JournalCounts)

    def __post_init__(self) -> None:
        self.directory = Path(self.directory)
        self.path = self.directory / FILE_NAME
        #: the stamps of the gateway (events, audit, values): never back, across restarts
        self.hlc = HybridClock(lambda: round(self.clock() * NANOS))
        self._cond = threading.Condition()
        self._queue: collections.deque[tuple[int, db.DbRow]] = collections.deque()
        self._pending_bytes = 0
        self._tickets = 0
        self._done = 0
        self._done_cond = threading.Condition()
        self._watchers: list[tuple[int, int, Callable[[], None]]] = []
        self._order = itertools.count()
        self._values: dict[str, Entry] = {}
        self._value_sources: list[Callable[[], Iterable[Entry]]] = []
        self._values_lock = threading.Lock()
        self._stopping = False
        self._running = False
        self._lock = files.FileLock(self.directory)
        #: the database as the writer uses it (``writer.py``)
        self.disk = DiskWriter(
            self.path, self.sync, self.max_mb, self.keep_days, self.clock, self.hlc, self.counts, self
        )
        self._thread: threading.Thread | None = None
        self._logs = {k: RateLimitedLog(log, LOG_PERIOD_S) for k in ("drop", "refuse", "remove", "fail")}
        #: every seq handed in (journaled or not) and those not in the database yet
        self._seen = SeqMarks()
        self._unsaved: dict[str, int] = {}
        self._marks_dirty = False

    # ------------------------------------------------------------------ open, start, stop
    def open(self) -> None:
        """Lock the directory, open (or create) the database, a damaged one set aside. Raises
        ``files.JournalInUse`` when another gateway has it, OSError or sqlite3.Error when the
        directory cannot hold one."""
        self.directory.mkdir(parents=True, exist_ok=True)
        self._lock.acquire()
        try:
            with self._cond:
                known = SeqMarks(dict(self._seen.seqs), self.hlc.last_ns)
            marks = self.disk.open(known)
            with self._cond:
                self._seen.merge(marks)
            self.hlc.observe(marks.hlc_ns)
        except BaseException:
            self._lock.release()
            raise
        files.prune_aside(self.path, self.keep_days * 86400.0, self.clock())
        ahead = self.hlc.ahead_s()
        if ahead > 1.0:
            log.warning(
                "journal %s holds times %.1f s ahead of this clock (it was set back): stamps "
                "go on from them, 1 ns apart, until the clock catches up", self.path, ahead,
            )  # fmt: skip

    def start(self, threads: ThreadRegistry | None = None) -> None:
        if self.disk.con is None:
            self.open()
        self._stopping = False
        self._running = True
        reg = threads if threads is not None else ThreadRegistry()
        self._thread = reg.start("journal-writer", self._run)

    def stop(self, timeout_s: float = 5.0) -> None:
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.warning("journal %s: the writer did not finish in %g s (the disk?)", self.path, timeout_s)
                return  # its connection is still in use: the process ends with it
            self._thread = None
        self._running = False
        if self.disk.con is not None:  # opened (never the copy beside another's database)
            self.disk.write_marks(force=True)
        self.disk.close()
        self._lock.release()

    def last_seqs(self) -> dict[str, int]:
        """The highest ``seq`` per key ever handed to this journal (kept across trims, drops,
        damage and restarts)."""
        with self._cond:
            return dict(self._seen.seqs)

    @property
    def set_aside(self) -> Path | None:
        """The damaged file set aside at open (None: none)."""
        return self.disk.set_aside

    def marks_to_copy(self) -> SeqMarks | None:
        """The marks as they are now, when they changed since the last copy (the writer)."""
        with self._cond:
            if not self._marks_dirty:
                return None
            self._marks_dirty = False
            return SeqMarks(dict(self._seen.seqs), self.hlc.last_ns)

    def keep_unsaved(self, marks: dict[str, int]) -> None:
        """Marks of rows the writer could not commit: saved with the next commit (and copied)."""
        with self._cond:
            for k, seq in marks.items():
                self._unsaved[k] = max(self._unsaved.get(k, 0), seq)
            self._marks_dirty = True

    # ------------------------------------------------------------------ writing (any thread)
    def append(self, entry: Entry) -> int:
        """Queue an entry; its ticket (for ``wait`` / ``when_done``), or 0 when it is not
        queued (refused, or dropped: the queue is full)."""
        row = intake(entry)
        if isinstance(row, str):
            self._refuse(row)
            return 0
        self.hlc.observe(ns_of_ntp64(row[0] + db.T_BIAS))
        size = len(row[5]) + len(row[2]) + db.ROW_OVERHEAD
        with self._cond:
            self._note_seq(row)
            if len(self._queue) >= self.max_pending or self._pending_bytes + size > self.max_pending_bytes:
                self.counts.dropped += 1
                self._unsaved[row[2]] = max(self._unsaved.get(row[2], 0), row[4] or 0)
                dropped = self.counts.dropped
                ticket = 0
            else:
                self._tickets += 1
                ticket = self._tickets
                self._queue.append((ticket, row))
                self._pending_bytes += size
                self._cond.notify()
        if not ticket:
            self._logs["drop"].warning("queue", "journal behind: entries dropped (%d so far)", dropped)
        return ticket

    def _note_seq(self, row: db.DbRow) -> None:
        key, seq = row[2], row[4]
        if seq is not None and seq > self._seen.seqs.get(key, -1):
            self._seen.seqs[key] = seq
            self._marks_dirty = True

    def _refuse(self, why: str) -> None:
        self.counts.refused += 1
        self._logs["refuse"].warning(
            "refused", "journal: entry refused: %s (%d refused so far)", why, self.counts.refused
        )

    def wait(self, ticket: int, timeout_s: float) -> bool:
        """Block until the entry of ``ticket`` is committed or dropped (True), at most
        ``timeout_s`` (False)."""
        with self._done_cond:
            return self._done_cond.wait_for(lambda: self._done >= ticket, timeout_s)

    def when_done(self, ticket: int, fn: Callable[[], None]) -> None:
        """``fn()`` once the entry of ``ticket`` is committed or dropped (on the writer, or
        here when it already is or too many wait)."""
        with self._done_cond:
            now = self._done >= ticket or len(self._watchers) >= MAX_WATCHERS
            if not now:
                heapq.heappush(self._watchers, (ticket, next(self._order), fn))
        if now:
            fn()

    def upkeep_now(self) -> None:
        """The writer looks for expired entries at its next step (after the clock changed)."""
        self.disk.next_keep = 0.0
        with self._cond:
            self._cond.notify()

    def note_unjournaled(self) -> None:
        """An event was published before its commit (the bound on waiting for it passed)."""
        self.counts.unjournaled += 1

    def value(self, entry: Entry) -> None:
        """The latest value sample of its key for the current window (``values_ms``)."""
        if self.values_ms:
            with self._values_lock:
                self._values[entry.key] = entry

    def values_from(self, source: Callable[[], Iterable[Entry]]) -> None:
        """``source`` gives, once per window on the writer's thread, the value samples to keep
        of that window."""
        self._value_sources.append(source)

    def _window(self) -> list[db.DbRow]:
        with self._values_lock:
            window, self._values = self._values, {}
        entries = list(window.values())
        for source in self._value_sources:
            try:
                entries.extend(source())
            except Exception as exc:  # noqa: BLE001 - a failing source must not stop the journal
                self._logs["fail"].warning("source", "journal: reading the values of a window failed: %r", exc)
        rows = []
        for e in entries:
            row = intake(e)
            if isinstance(row, str):
                self._refuse(row)
                continue
            rows.append(row)
            with self._cond:
                self._note_seq(row)
        return rows

    # ------------------------------------------------------------------ the writer thread
    def _run(self) -> None:
        values_s = self.values_ms / 1000.0
        next_values = time.monotonic() + values_s
        while True:
            try:
                with self._cond:
                    while not self._queue and not self._stopping:
                        now = time.monotonic()
                        wake = min(self.disk.next_keep, next_values if values_s else float("inf"))
                        if wake <= now:
                            break
                        self._cond.wait(wake - now)
                    batch = self._take()
                    stopping = self._stopping and not self._queue
                rows = [r for _, r in batch]
                if values_s and (stopping or time.monotonic() >= next_values):
                    next_values = time.monotonic() + values_s
                    rows.extend(self._window())
                try:
                    if rows:
                        with self._cond:
                            marks, self._unsaved = self._unsaved, {}
                        self.disk.write(rows, marks)
                finally:
                    if batch:
                        self._finish(batch[-1][0])
                self.disk.upkeep()
                if stopping:
                    return
            except Exception as exc:  # noqa: BLE001 - the writer never dies of a step
                self.counts.last_error = f"{type(exc).__name__}: {exc}"
                self._logs["fail"].warning("step", "journal %s: a step of the writer failed: %r", self.path, exc)
                time.sleep(0.05)

    def _take(self) -> list[tuple[int, db.DbRow]]:
        """Under the lock: the next commit's entries, at most ``BATCH_ROWS`` and about
        ``disk.batch_bytes`` (one at least)."""
        batch: list[tuple[int, db.DbRow]] = []
        size = 0
        q = self._queue
        while q and len(batch) < BATCH_ROWS and (not batch or size < self.disk.batch_bytes):
            item = q.popleft()
            n = len(item[1][5]) + len(item[1][2]) + db.ROW_OVERHEAD
            size += n
            self._pending_bytes -= n
            batch.append(item)
        return batch

    def _finish(self, ticket: int) -> None:
        with self._done_cond:
            self._done = max(self._done, ticket)
            self._done_cond.notify_all()
            ready = []
            while self._watchers and self._watchers[0][0] <= self._done:
                ready.append(heapq.heappop(self._watchers)[2])
        for fn in ready:
            try:
                fn()
            except Exception as exc:  # noqa: BLE001
                self._logs["fail"].warning("watcher", "journal: a callback after commit failed: %r", exc)

    # ------------------------------------------------------------------ reading (any thread)
    def read(
        self,
        keys: Iterable[str] | None = None,
        *,
        kinds: Iterable[str] | None = None,
        node: str | None = None,
        t_from: int | None = None,
        t_to: int | None = None,
        chunk: int = db.READ_CHUNK,
    ) -> Iterator[Row]:
        """Entries in (time, id) order between the inclusive NTP64 bounds (None: open), read a
        page at a time on a connection of the reader's own: never all in memory."""
        return db.read(self.path, keys, kinds, node, t_from, t_to, chunk)

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """For /healthz: the figures, whether it journals and, if not, why."""
        c = self.counts
        with self._cond:
            pending, pending_bytes = len(self._queue), self._pending_bytes
        now = time.monotonic()
        busy = self.disk.busy_since
        full = now - self.disk.full_at < FULL_SHOWN_S
        error = c.last_error
        stalled = busy is not None and now - busy > STALL_S
        journaling = self._running and error is None and not stalled
        if busy is not None and stalled:
            error = (
                f"the journal's disk does not answer: a commit has waited {now - busy:.1f} s "
                "(events are published without waiting for it)"
            )
        elif full and error is None:  # trimming to fit: still journaling
            error = (
                f"disk full at {self.directory}: the oldest entries go to make room "
                f"(journal.max_mb {self.max_mb:g} does not fit)"
            )
        return {
            "path": str(self.path),
            "journaling": journaling,
            "written": c.written,
            "dropped": c.dropped,
            "refused": c.refused,
            "removed": c.removed,
            "published_unjournaled": c.unjournaled,
            "pending": pending,
            "pending_bytes": pending_bytes,
            "disk_full": full,
            "error": error,
        }
