"""The journal's storage: one SQLite database (standard library, WAL mode) in ``journal.path``,
written by one thread (``journal-writer``), read by any thread through connections of its own.

What goes in (``Entry``): every state and EMCY sample as published (``append``, write ahead:
the entry's ``on_commit`` runs after its commit, and the bridge publishes it there), the latest
value sample of each signal per ``values_ms`` window (``value``: a dict assignment, the writer
takes the window's latest; or ``values_from``: the writer asks a source once per window), and
the audit of every write (``append`` without a callback).

Rules held here, once:

* **Group commit**: the writer takes everything queued (at most ``BATCH_ROWS``), inserts it in
  one transaction, commits, then runs the callbacks in the order the entries came. While it
  commits, new entries queue: under load a commit carries many, idle ones carry one.
* **Never blocks a caller**: ``append`` and ``value`` only queue (under a lock, no I/O). When
  ``MAX_PENDING`` entries wait (a slow disk), a new entry is not journaled (``dropped``) but its
  callback keeps its place in the order; a failing commit (disk full, I/O error) drops its rows
  and the callbacks run all the same: the gateway goes on serving and publishing. Drops are
  counted, logged at most once a minute and shown in ``status()`` (``/healthz``).
* **Bounded**: in each commit, before its rows go in, when the live pages and the new rows
  would pass ``max_mb`` the oldest entries go until they fit in 90 % of it; every minute
  entries older than ``keep_days`` go (in the next commit). Both counted in
  ``removed`` and logged at most once a minute. Freed pages are reused: the file stops growing.
* **Schema versioned** (``PRAGMA user_version``); a file that is not a journal of this version,
  or fails SQLite's quick check, is renamed aside (``<name>.damaged-<UTC time>``, never deleted)
  and a fresh journal starts, with one log line naming the file (``open``).

Times are Zenoh's (NTP64: seconds since 1970 << 32 | fraction), stored with ``T_BIAS``
subtracted so that they fit SQLite's signed 64-bit integers in order.

Imports: the standard library, runtime.ratelimit, runtime.threads. Never zenoh (timestamps are taken by duck
type: ``get_time_as_ntp64``, ``get_id``), nor any adapter.
"""

from __future__ import annotations

import collections
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from gateway.runtime.ratelimit import RateLimitedLog
from gateway.runtime.threads import ThreadRegistry

log = logging.getLogger("gateway.journal")

SCHEMA_VERSION = 1
FILE_NAME = "journal.sqlite3"
T_BIAS = 1 << 63  # NTP64 is unsigned; SQLite integers are signed
BATCH_ROWS = 2000  # entries per commit at most
MAX_PENDING = 50_000  # entries waiting for the writer before new ones are dropped
LOG_PERIOD_S = 60.0  # drops and removals are logged at most once per period
KEEP_CHECK_S = 60.0  # how often entries older than keep_days are looked for
READ_CHUNK = 500  # rows per read of a history
ROW_OVERHEAD = 80  # bytes of a row and its index entries besides payload and key (estimate)

SCHEMA = """
CREATE TABLE entries(
  id INTEGER PRIMARY KEY,
  t INTEGER NOT NULL,
  kind TEXT NOT NULL,
  key TEXT NOT NULL,
  node TEXT,
  seq INTEGER,
  payload BLOB NOT NULL,
  tid BLOB
);
CREATE INDEX entries_key_t ON entries(key, t);
CREATE INDEX entries_t ON entries(t);
"""


def ntp64_of_time(t: float) -> int:
    """Seconds since 1970 as Zenoh's NTP64."""
    secs = int(t // 1)
    return (secs << 32) | int((t - secs) * (1 << 32))


def time_of_ntp64(n: int) -> float:
    return (n >> 32) + (n & 0xFFFFFFFF) / (1 << 32)


class Entry(NamedTuple):
    """One journal entry. ``stamp``: a Zenoh timestamp (of the publication) or an NTP64 int."""

    stamp: Any
    kind: str  # state | emcy | value | audit
    key: str  # the Zenoh key it was published on (``<prefix>/audit`` for the audit)
    node: str | None
    seq: int | None
    payload: bytes | str  # as published (text is stored as its UTF-8 bytes)


class Row(NamedTuple):
    """An entry read back: ``t`` the NTP64 time, ``tid`` the timestamp's id (None: ours)."""

    id: int
    t: int
    kind: str
    key: str
    node: str | None
    seq: int | None
    payload: bytes
    tid: bytes | None


def _stamp(e: Entry) -> tuple[int, bytes | None]:
    s = e.stamp
    if isinstance(s, int):
        return s, None
    return int(str(s.get_time_as_ntp64())), bytes(s.get_id())


def path_problem(directory: str | os.PathLike[str]) -> str | None:
    """Why the journal cannot live in ``directory`` (created if missing), or None."""
    d = Path(directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
        probe = d / f".journal-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        return f"{directory} cannot be created or written: {exc.strerror or exc}"
    return None


def _damage(path: Path) -> str | None:
    """Why an existing journal file cannot be used (None: it can)."""
    try:
        con = sqlite3.connect(path)
        try:
            ok = con.execute("PRAGMA quick_check").fetchone()[0]
            if ok != "ok":
                return f"quick check: {ok}"
            version = con.execute("PRAGMA user_version").fetchone()[0]
            if version != SCHEMA_VERSION:
                return f"schema version {version}, this gateway writes {SCHEMA_VERSION}"
            con.execute("SELECT id, t, kind, key, node, seq, payload, tid FROM entries LIMIT 1")
        finally:
            con.close()
    except sqlite3.Error as exc:
        return str(exc)
    return None


def set_aside(path: Path, why: str, now: float) -> Path:
    """Rename a damaged journal (and its WAL files) aside; one log line naming the file."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(now))
    aside = path.with_name(f"{path.name}.damaged-{stamp}")
    n = 1
    while aside.exists():
        n += 1
        aside = path.with_name(f"{path.name}.damaged-{stamp}-{n}")
    for suffix in ("-wal", "-shm"):
        extra = path.with_name(path.name + suffix)
        if extra.exists():
            extra.rename(aside.with_name(aside.name + suffix))
    path.rename(aside)
    log.warning("journal %s is damaged (%s): kept as %s; a fresh journal starts", path, why, aside)
    return aside


@dataclass
class JournalCounts:
    written: int = 0  # entries committed
    dropped: int = 0  # entries not journaled (queue full, failed commit)
    removed: int = 0  # entries removed by max_mb or keep_days
    commits: int = 0
    last_error: str | None = None


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
    counts: JournalCounts = field(default_factory=JournalCounts)

    def __post_init__(self) -> None:
        self.directory = Path(self.directory)
        self.path = self.directory / FILE_NAME
        self._cond = threading.Condition()
        self._queue: collections.deque[tuple[Entry | None, Callable[[], None] | None]] = (
            collections.deque()
        )
        self._values: dict[str, Entry] = {}
        self._value_sources: list[Callable[[], Iterable[Entry]]] = []
        self._values_lock = threading.Lock()
        self._stopping = False
        self._con: sqlite3.Connection | None = None
        self._thread: threading.Thread | None = None
        self._droplog = RateLimitedLog(log, LOG_PERIOD_S)
        self._removelog = RateLimitedLog(log, LOG_PERIOD_S)
        self._next_keep_check = 0.0
        self._next_values = 0.0
        #: the damaged file set aside at open (None: none)
        self.set_aside: Path | None = None
        #: highest seq per key found at open (``last_seqs``)
        self._last_seqs: dict[str, int] = {}

    # ------------------------------------------------------------------ open, start, stop
    def open(self) -> None:
        """Create or open the database (a damaged one is set aside); raises OSError or
        sqlite3.Error when the directory cannot hold one."""
        self.directory.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            why = _damage(self.path)
            if why is not None:
                self.set_aside = set_aside(self.path, why, self.clock())
        con = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        con.execute("PRAGMA journal_mode=WAL")
        con.execute(f"PRAGMA synchronous={'FULL' if self.sync == 'full' else 'NORMAL'}")
        con.execute("PRAGMA journal_size_limit=16777216")
        if con.execute("PRAGMA user_version").fetchone()[0] == 0:
            con.executescript(SCHEMA + f"PRAGMA user_version={SCHEMA_VERSION};")
        self._last_seqs = {
            k: s
            for k, s in con.execute(
                "SELECT key, MAX(seq) FROM entries WHERE seq IS NOT NULL GROUP BY key"
            )
        }
        self._con = con

    def start(self, threads: ThreadRegistry | None = None) -> None:
        if self._con is None:
            self.open()
        self._stopping = False
        reg = threads if threads is not None else ThreadRegistry()
        self._thread = reg.start("journal-writer", self._run)

    def stop(self, timeout_s: float = 5.0) -> None:
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
        if self._con is not None:
            self._con.close()
            self._con = None

    def last_seqs(self) -> dict[str, int]:
        """The highest ``seq`` journaled per key when the journal was opened."""
        return dict(self._last_seqs)

    # ------------------------------------------------------------------ writing (any thread)
    def append(self, entry: Entry, on_commit: Callable[[], None] | None = None) -> None:
        """Queue an entry; ``on_commit`` runs on the writer once it is committed (or dropped),
        in the order of the appends."""
        with self._cond:
            if len(self._queue) >= self.max_pending:
                self.counts.dropped += 1
                self._droplog.warning(
                    "queue", "journal behind: entries dropped (%d so far)", self.counts.dropped
                )
                self._queue.append((None, on_commit))
            else:
                self._queue.append((entry, on_commit))
            self._cond.notify()

    def value(self, entry: Entry) -> None:
        """The latest value sample of its key for the current window (``values_ms``)."""
        if self.values_ms:
            with self._values_lock:
                self._values[entry.key] = entry

    def values_from(self, source: Callable[[], Iterable[Entry]]) -> None:
        """``source`` gives, once per window on the writer's thread, the latest value samples
        published since the last window (the publisher only keeps its latest: no call per
        sample)."""
        self._value_sources.append(source)

    def _window(self) -> list[Entry]:
        with self._values_lock:
            window, self._values = self._values, {}
        rows = list(window.values())
        for source in self._value_sources:
            try:
                rows.extend(source())
            except Exception:  # noqa: BLE001 - a failing source must not stop the journal
                log.exception("journal: reading the values of a window failed")
        return rows

    # ------------------------------------------------------------------ the writer thread
    def _run(self) -> None:
        values_s = self.values_ms / 1000.0
        self._next_values = time.monotonic() + values_s
        while True:
            with self._cond:
                while not self._queue and not self._stopping:
                    if not values_s:
                        self._cond.wait()
                        continue
                    left = self._next_values - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
                n = min(len(self._queue), BATCH_ROWS)
                batch = [self._queue.popleft() for _ in range(n)]
                stopping = self._stopping and not self._queue
            rows = [e for e, _ in batch if e is not None]
            if values_s and (stopping or time.monotonic() >= self._next_values):
                self._next_values = time.monotonic() + values_s
                rows.extend(self._window())
            if rows:
                self._commit(rows)
            for _, callback in batch:
                if callback is not None:
                    try:
                        callback()
                    except Exception:  # noqa: BLE001 - one failed publication must not stop us
                        log.exception("journal: a callback after commit failed")
            if stopping:
                return

    def _commit(self, rows: list[Entry]) -> None:
        con = self._con
        assert con is not None
        try:
            params = []
            for e in rows:
                t, tid = _stamp(e)
                data = e.payload.encode() if isinstance(e.payload, str) else e.payload
                params.append((t - T_BIAS, e.kind, e.key, e.node, e.seq, data, tid))
            con.execute("BEGIN")
            removed = self._bound(con, sum(len(p[5]) + len(p[2]) + ROW_OVERHEAD for p in params))
            con.executemany(
                "INSERT INTO entries(t, kind, key, node, seq, payload, tid)"
                " VALUES (?, ?, ?, ?, ?, ?, ?)",
                params,
            )
            con.execute("COMMIT")
        except (sqlite3.Error, ValueError, TypeError, AttributeError) as exc:
            if con.in_transaction:
                con.execute("ROLLBACK")
            self.counts.dropped += len(rows)
            self.counts.last_error = str(exc)
            self._droplog.warning(
                "commit",
                "journal %s: %s; %d entries not journaled so far",
                self.path,
                exc,
                self.counts.dropped,
            )
            return
        self.counts.written += len(rows)
        self.counts.commits += 1
        self.counts.last_error = None
        if removed:
            self.counts.removed += removed
            self._removelog.info(
                "removed",
                "journal %s bounded (max_mb %s, keep_days %s): %d oldest entries removed so far",
                self.path,
                self.max_mb,
                self.keep_days,
                self.counts.removed,
            )

    def _bound(self, con: sqlite3.Connection, incoming: int) -> int:
        """Oldest entries first, in the transaction of the rows about to come (``incoming``
        bytes, estimated): room for them within ``max_mb`` (down to 90 % of it when trimming);
        past ``keep_days``."""
        now = self.clock()
        removed = 0
        if now >= self._next_keep_check:
            self._next_keep_check = now + KEEP_CHECK_S
            oldest = ntp64_of_time(now - self.keep_days * 86400.0) - T_BIAS
            removed += con.execute("DELETE FROM entries WHERE t < ?", (oldest,)).rowcount
        limit = self.max_mb * 1024 * 1024
        if self.live_bytes(con) + incoming > limit:
            while self.live_bytes(con) + incoming > 0.9 * limit:
                total = con.execute("SELECT COUNT(*) FROM entries").fetchone()[0]
                if not total:
                    break
                chunk = max(100, total // 20)
                removed += con.execute(
                    "DELETE FROM entries WHERE id IN (SELECT id FROM entries ORDER BY id LIMIT ?)",
                    (chunk,),
                ).rowcount
        return removed

    @staticmethod
    def live_bytes(con: sqlite3.Connection) -> int:
        page = con.execute("PRAGMA page_size").fetchone()[0]
        count = con.execute("PRAGMA page_count").fetchone()[0]
        free = con.execute("PRAGMA freelist_count").fetchone()[0]
        return int((count - free) * page)

    # ------------------------------------------------------------------ reading (any thread)
    def read(
        self,
        keys: Iterable[str] | None = None,
        *,
        kinds: Iterable[str] | None = None,
        node: str | None = None,
        t_from: int | None = None,
        t_to: int | None = None,
        from_open: bool = False,
        to_open: bool = False,
        chunk: int = READ_CHUNK,
    ) -> Iterator[Row]:
        """Entries in time order (NTP64 bounds, inclusive unless ``*_open``), read ``chunk``
        rows at a time on a connection of the reader's own: never all in memory."""
        where: list[str] = []
        args: list[Any] = []
        if keys is not None:
            ks = list(keys)
            where.append(f"key IN ({','.join('?' * len(ks))})")
            args += ks
        if kinds is not None:
            kl = list(kinds)
            where.append(f"kind IN ({','.join('?' * len(kl))})")
            args += kl
        if node is not None:
            where.append("node = ?")
            args.append(node)
        if t_from is not None:
            where.append("t > ?" if from_open else "t >= ?")
            args.append(t_from - T_BIAS)
        if t_to is not None:
            where.append("t < ?" if to_open else "t <= ?")
            args.append(t_to - T_BIAS)
        base = "SELECT id, t, kind, key, node, seq, payload, tid FROM entries WHERE " + (
            " AND ".join(where) or "1"
        )
        uri = f"{self.path.resolve().as_uri()}?mode=ro"  # percent-encoded: any file name
        con = sqlite3.connect(uri, uri=True, check_same_thread=False)
        try:
            last: tuple[int, int] | None = None
            while True:
                if last is None:
                    q, a = base, args
                else:
                    q = base + " AND (t > ? OR (t = ? AND id > ?))"
                    a = [*args, last[0], last[0], last[1]]
                rows = con.execute(q + " ORDER BY t, id LIMIT ?", (*a, chunk)).fetchall()
                for r in rows:
                    yield Row(r[0], r[1] + T_BIAS, *r[2:])
                if len(rows) < chunk:
                    return
                last = (rows[-1][1], rows[-1][0])
        finally:
            con.close()

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """For /healthz: the figures and the last error (None when the last commit worked)."""
        c = self.counts
        with self._cond:
            pending = len(self._queue)
        return {
            "path": str(self.path),
            "written": c.written,
            "dropped": c.dropped,
            "removed": c.removed,
            "pending": pending,
            "error": c.last_error,
        }
