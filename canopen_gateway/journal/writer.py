"""The journal's database as its writer thread uses it (``DiskWriter``): opened (a damaged file
set aside, the marks gathered from the file, its copy and a damaged file), each commit made
(``write``: retried after room was made on a full disk or a damaged file was set aside, then
in halves; what cannot be committed is dropped, counted), the room it may take (``budget``:
``max_mb``, less when the disk has less), and the bounded upkeep between commits (a chunk of
expired entries, the WAL's bound, the copy of the marks, the damaged files set aside).

One thread only (``journal-writer``; ``open`` before it starts). What it counts is the
journal's (``JournalCounts``); what it needs of the journal is ``Owner``: the marks to copy and
the marks of rows it could not write.

Imports: the standard library, journal.clock, journal.db, journal.files, runtime.ratelimit.
Never zenoh nor an adapter.
"""

from __future__ import annotations

import logging
import os
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from canopen_gateway.journal import db, files
from canopen_gateway.journal.clock import NANOS, HybridClock, ns_of_ntp64, ntp64_of_ns
from canopen_gateway.journal.files import SeqMarks
from canopen_gateway.runtime.ratelimit import RateLimitedLog

log = logging.getLogger("gateway.journal")

LOG_PERIOD_S = 60.0  # drops, failures and removals are logged at most once per period
KEEP_CHECK_S = 60.0  # how often entries older than keep_days are looked for (when none were)
MARKS_PERIOD_S = 1.0  # the copy of the marks beside the database, at most this often
WAL_MIN, WAL_MAX = 64 << 10, 16 << 20  # the WAL's bound: an eighth of the budget, within these
BATCH_MIN_BYTES, BATCH_MAX_BYTES = 32 << 10, 4 << 20  # bytes per commit: 1/16 of the budget
MB = 1024 * 1024


@dataclass
class JournalCounts:
    written: int = 0  # entries committed
    dropped: int = 0  # entries not journaled (queue full, failed commit)
    refused: int = 0  # entries refused at intake (out of range, not an entry)
    removed: int = 0  # entries removed by max_mb, a full disk or keep_days
    unjournaled: int = 0  # events published before their commit (the 200 ms bound passed)
    commits: int = 0
    last_error: str | None = None


class Owner(Protocol):
    """What the writer needs of the journal."""

    def marks_to_copy(self) -> SeqMarks | None: ...
    def keep_unsaved(self, marks: dict[str, int]) -> None: ...


@dataclass(eq=False)
class DiskWriter:
    """See the module docstring."""

    path: Path
    sync: str
    max_mb: float
    keep_days: float
    clock: Callable[[], float]
    hlc: HybridClock
    counts: JournalCounts
    owner: Owner
    con: sqlite3.Connection | None = field(default=None, init=False)
    #: the damaged file set aside at open (None: none)
    set_aside: Path | None = field(default=None, init=False)
    #: monotonic: while a commit runs, since when; the last time the disk was full
    busy_since: float | None = field(default=None, init=False)
    full_at: float = field(default=float("-inf"), init=False)
    #: bytes of entries per commit (``budget``)
    batch_bytes: int = field(default=BATCH_MAX_BYTES, init=False)

    def __post_init__(self) -> None:
        self.directory = self.path.parent
        self._logs = {k: RateLimitedLog(log, LOG_PERIOD_S) for k in ("drop", "fail", "remove")}
        self._wal_bytes = WAL_MAX
        #: monotonic: when the upkeep looks for expired entries next (the first step: at once)
        self.next_keep = 0.0
        self._marks_written = 0.0

    def open(self, known: SeqMarks, why: str | None = None) -> SeqMarks:
        """Open (or create) the database, a damaged one set aside; the marks of everything it
        knows of (``known``: the journal's), saved in it and returned."""
        marks = files.read_marks(self.path)
        marks.merge(known)
        if why is None and self.path.exists():
            why = files.damage(self.path, db.CHECKS, db.SCHEMA_VERSION, db.KNOWN_VERSIONS)
        if why is not None:
            marks.merge(files.salvage_marks(self.path))
            self.set_aside = files.set_aside(self.path, why, self.clock())
        try:
            con = db.connect(self.path, self.sync, self._wal_bytes)
            marks.merge(db.load_marks(con))
        except sqlite3.Error as exc:
            if why is None and files.is_damage(exc):
                return self.open(known, str(exc))
            raise
        db.save_marks(con, marks)
        con.execute("PRAGMA busy_timeout=100")  # only checkpoints wait (readers): briefly
        self.con = con
        return marks

    def close(self) -> None:
        con, self.con = self.con, None
        if con is not None:
            con.close()

    def write(self, rows: list[db.DbRow], marks: dict[str, int]) -> None:
        """Commit ``rows``; after a full disk was made room for (or a damaged file set aside)
        once more, then in halves; what cannot be committed is dropped, counted."""
        self._commit(rows, marks, retry=True)

    def _commit(self, rows: list[db.DbRow], marks: dict[str, int], retry: bool) -> None:
        for r in rows:
            if r[4] is not None and r[4] > marks.get(r[2], -1):
                marks[r[2]] = r[4]
        con = self.con
        assert con is not None
        self.busy_since = time.monotonic()
        try:
            hlc = max(ns_of_ntp64(max(r[0] for r in rows) + db.T_BIAS), self.hlc.last_ns)
            removed = db.commit(con, rows, marks, hlc, self.budget(con))
        except Exception as exc:  # noqa: BLE001 - any error: handled, counted, never raised
            self.busy_since = None
            if retry and self._recover(exc):
                return self._commit(rows, marks, retry=False)
            if len(rows) > 1 and files.is_full(exc):  # what fits goes in
                half = len(rows) // 2
                self._commit(rows[:half], {}, retry=False)
                return self._commit(rows[half:], marks, retry=False)
            return self._dropped(rows, marks, exc)
        self.busy_since = None
        self.counts.written += len(rows)
        self.counts.commits += 1
        self.counts.last_error = None
        self._removed(removed, "room")

    def _recover(self, exc: Exception) -> bool:
        """After a failed commit: make room on a full disk, set a damaged file aside; True when
        a retry may work."""
        con = self.con
        assert con is not None
        if files.is_full(exc):
            self.full_at = time.monotonic()
            return self._recover_full(con)
        if files.is_damage(exc):
            con.close()
            self.con = None
            self.open(SeqMarks(), f"{exc} (while writing)")
            return True
        return False

    def _recover_full(self, con: sqlite3.Connection) -> bool:
        """The disk is full: the WAL emptied into the database, a chunk of the oldest entries
        deleted, emptied again (the pages freed are reused: the file does not grow)."""
        removed = 0
        try:
            self._checkpoint(con, truncate=True)
            removed = db.delete_oldest(con, db.TRIM_CHUNK // 4)
            self._checkpoint(con, truncate=True)
        except Exception:  # noqa: BLE001 - a retry is still worth it
            self._logs["fail"].warning("full", "journal %s: the disk is full; making room failed", self.path)
        self._removed(removed, "disk full")
        return True

    def _dropped(self, rows: list[db.DbRow], marks: dict[str, int], exc: Exception) -> None:
        self.owner.keep_unsaved(marks)  # the marks of rows not written: the next commit's
        self.counts.dropped += len(rows)
        self.counts.last_error = str(exc) or type(exc).__name__
        self._logs["drop"].warning(
            "commit", "journal %s: %s; %d entries not journaled so far", self.path,
            self.counts.last_error, self.counts.dropped,
        )  # fmt: skip

    def _removed(self, removed: int, why: str) -> None:
        if not removed:
            return
        self.counts.removed += removed
        self._logs["remove"].info(
            "removed", "journal %s bounded (%s; max_mb %s, keep_days %s): %d oldest entries removed so far",
            self.path, why, self.max_mb, self.keep_days, self.counts.removed,
        )  # fmt: skip

    def budget(self, con: sqlite3.Connection) -> int:
        """Bytes the live pages may take: ``max_mb``, or less when the disk has less room (its
        free space and what the journal's files take) or the database a page limit."""
        total = int(self.max_mb * MB)
        try:
            st = os.statvfs(self.directory)
            wal = self.path.with_name(self.path.name + "-wal")
            used = sum(p.stat().st_size for p in (self.path, wal) if p.exists())
            room = int((used + st.f_bavail * st.f_frsize) * 0.95)
        except OSError:
            room = total
        page = con.execute("PRAGMA page_size").fetchone()[0]
        room = min(room, con.execute("PRAGMA max_page_count").fetchone()[0] * page)
        limited = room < total
        total = min(total, room)
        wal_bound = max(WAL_MIN, min(WAL_MAX, total // 8))
        if wal_bound != self._wal_bytes:
            self._set_wal(con, wal_bound)
        # a commit's pages may pass the WAL's bound before it is checkpointed: room for both
        self.batch_bytes = max(BATCH_MIN_BYTES, min(BATCH_MAX_BYTES, total // 16))
        budget = max(total - 2 * wal_bound - self.batch_bytes, total // 4)
        if limited and db.live_bytes(con) > 0.9 * budget:
            self.full_at = time.monotonic()
        return budget

    def _set_wal(self, con: sqlite3.Connection, wal: int) -> None:
        self._wal_bytes = wal
        db.set_wal_bound(con, wal)

    def _checkpoint(self, con: sqlite3.Connection, truncate: bool) -> None:
        try:
            db.checkpoint(con, truncate)
        except sqlite3.OperationalError:
            pass  # readers in the way (busy): the next step tries again

    def upkeep(self) -> None:
        """The bounded steps between commits: a chunk of expired entries, the WAL bound, the
        copy of the marks, the damaged files set aside."""
        con = self.con
        if con is None:
            return
        now = time.monotonic()
        if now >= self.next_keep:
            cutoff = ntp64_of_ns(round((self.clock() - self.keep_days * 86400.0) * NANOS))
            try:
                n = db.delete_expired(con, cutoff) if cutoff > 0 else 0
            except sqlite3.Error as exc:
                n = 0
                self._logs["fail"].warning("keep", "journal %s: removing expired entries: %s", self.path, exc)
            self._removed(n, "keep_days")
            if n < db.TRIM_CHUNK:  # none left: look again later
                self.next_keep = now + KEEP_CHECK_S
                files.prune_aside(self.path, self.keep_days * 86400.0, self.clock())
        wal = self.path.with_name(self.path.name + "-wal")
        try:
            if wal.stat().st_size > 2 * self._wal_bytes:
                self._checkpoint(con, truncate=True)
        except OSError:
            pass
        self.write_marks()

    def write_marks(self, force: bool = False) -> None:
        """The copy of the marks beside the database (at most every ``MARKS_PERIOD_S``)."""
        now = time.monotonic()
        if not force and now - self._marks_written < MARKS_PERIOD_S:
            return
        snapshot = self.owner.marks_to_copy()
        if snapshot is None:
            return
        self._marks_written = now
        try:
            files.write_marks(self.path, snapshot, fsync=self.sync == "full")
        except OSError as exc:
            self.owner.keep_unsaved({})  # copy again next time
            log.debug("journal: the copy of the marks was not written: %s", exc)
