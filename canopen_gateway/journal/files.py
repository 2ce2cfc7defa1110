"""The journal's files around its database, and what is decided about them before SQLite runs:

* **One writer per file** (``FileLock``): an OS lock (``flock``) on ``journal.lock`` beside the
  database, holding the pid of the gateway that has it. A second gateway on the same
  ``journal.path`` is refused at once (``JournalInUse``: the path and the holder's pid), never
  left to interleave its rows or to take a busy database for a damaged one. The lock goes with
  the process (a killed gateway leaves no stale lock).
* **Damage** (``damage``): only what is really damaged sets a file aside: not a database (its
  header), a file shorter than its pages (truncated), SQLite's own "malformed" or "not a
  database" on the first reads, or a schema this gateway does not know. A locked or busy
  database, a full disk, an I/O or permission error are not damage: they raise. The check reads
  a few pages (the header, the last rows of the table and its indexes, the marks), never the
  whole file: a full 256 MB journal opens in milliseconds.
* **Set aside** (``set_aside``): a damaged file (and its WAL files) is renamed
  ``<name>.damaged-<UTC time>``, never deleted, with one log line; ``prune_aside`` keeps the
  newest ``DAMAGED_KEEP`` of them and none older than ``keep_days``.
* **The marks** (``SeqMarks``): the highest ``seq`` ever journaled per key and the newest time
  stamped, kept in the database (``marks``, ``meta``: trimming never touches them) and copied to
  ``journal.sqlite3.marks`` beside it (``write_marks``, atomically, at most once a second and at
  stop), so that a damaged database that cannot be read still hands them on: ``seq`` is never
  used twice on a key, whatever happens to the rows.

Imports: the standard library only. Never zenoh nor an adapter.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger("gateway.journal")

FILE_NAME = "journal.sqlite3"
LOCK_NAME = "journal.lock"
MARKS_SUFFIX = ".marks"
DAMAGED_KEEP = 3  # damaged files kept aside at most (the newest)
SQLITE_HEADER = b"SQLite format 3\x00"
#: SQLite result codes (primary) that mean the file itself is damaged
DAMAGE_CODES = frozenset({11, 26})  # SQLITE_CORRUPT, SQLITE_NOTADB


class JournalInUse(RuntimeError):
    """Another process holds the journal's lock."""

    def __init__(self, directory: Path, pid: str) -> None:
        self.reason = (
            f"is in use by another gateway (pid {pid or 'unknown'}): each gateway needs a "
            "journal.path of its own (a pair on one host too)"
        )
        super().__init__(f"{directory} {self.reason}")
        self.directory, self.pid = directory, pid


def is_damage(exc: BaseException) -> bool:
    """Whether a SQLite error says the file is damaged (not locked, busy, full or unreadable)."""
    code = getattr(exc, "sqlite_errorcode", None)
    if code is not None:
        return (code & 0xFF) in DAMAGE_CODES
    text = str(exc)
    return "malformed" in text or "not a database" in text


def is_full(exc: BaseException) -> bool:
    """Whether an error says the disk (or the database's page limit) is full."""
    if isinstance(exc, OSError):
        return exc.errno in (errno.ENOSPC, errno.EDQUOT)
    code = getattr(exc, "sqlite_errorcode", None)
    if code is not None:
        return (code & 0xFF) == 13  # SQLITE_FULL
    return "database or disk is full" in str(exc)


class FileLock:
    """The journal's OS lock (see the module docstring)."""

    def __init__(self, directory: Path) -> None:
        self.path = directory / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = ""
            with contextlib.suppress(OSError):
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise JournalInUse(self.path.parent, holder) from None
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    @staticmethod
    def holder(directory: Path) -> JournalInUse | None:
        """Whether another process holds the lock of the journal in ``directory`` (asked before
        anything opens, to name it beside the ports in use), taking nothing."""
        try:
            fd = os.open(directory / LOCK_NAME, os.O_RDWR)
        except OSError:
            return None  # no lock file (or none readable): the open says what is wrong
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return JournalInUse(directory, os.pread(fd, 32, 0).decode(errors="replace").strip())
            return None
        finally:
            os.close(fd)  # closing lets a lock taken here go
        return None

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            os.close(fd)  # closing lets the lock go


def damage(path: Path, tables: tuple[str, ...], version: int, known: tuple[int, ...]) -> str | None:
    """Why the existing database at ``path`` cannot be used (None: it can, in one of the
    ``known`` schema versions). Raises ``sqlite3.Error`` for what is not damage (locked, I/O)."""
    with open(path, "rb") as f:
        head = f.read(100)
    if not head:
        return None  # an empty file is an empty database
    if len(head) < 100 or not head.startswith(SQLITE_HEADER):
        return "not a SQLite database"
    page = int.from_bytes(head[16:18], "big")
    page = 65536 if page == 1 else page
    pages = int.from_bytes(head[28:32], "big")
    valid = head[24:28] == head[92:96]  # the in-header size is valid for this change counter
    wal = path.with_name(path.name + "-wal")
    has_wal = wal.exists() and wal.stat().st_size > 0
    if valid and not has_wal and pages * page > path.stat().st_size:
        return f"truncated: {path.stat().st_size} bytes, its header counts {pages} pages of {page}"
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=5.0)
    except sqlite3.Error as exc:
        if is_damage(exc):
            return str(exc)
        raise
    try:
        v = con.execute("PRAGMA user_version").fetchone()[0]
        if v == 0 and con.execute("PRAGMA schema_version").fetchone()[0] == 0:
            return None  # created, never written
        if v not in known:
            return f"schema version {v}, this gateway writes {version}"
        for table in tables:
            con.execute(table).fetchall()  # the last rows of each b-tree: a few pages
    except sqlite3.Error as exc:
        if is_damage(exc) or "no such" in str(exc):
            return str(exc)
        raise
    finally:
        con.close()
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


def prune_aside(path: Path, keep_s: float, now: float, keep: int = DAMAGED_KEEP) -> list[Path]:
    """Damaged files set aside beside ``path``: the newest ``keep`` stay, none older than
    ``keep_s``; the others (with their WAL files) are deleted. Returns those deleted."""
    aside = sorted(
        (p for p in path.parent.glob(f"{path.name}.damaged-*") if not p.name.endswith(("-wal", "-shm"))),
        key=lambda p: p.stat().st_mtime,
        reverse=True,
    )
    gone = []
    for i, p in enumerate(aside):
        if i >= keep or now - p.stat().st_mtime > keep_s:
            for extra in (p, p.with_name(p.name + "-wal"), p.with_name(p.name + "-shm")):
                with contextlib.suppress(FileNotFoundError):
                    extra.unlink()
            gone.append(p)
    if gone:
        log.info("journal: %d damaged file(s) set aside earlier deleted (%s)", len(gone), ", ".join(p.name for p in gone))
    return gone


@dataclass
class SeqMarks:
    """The highest ``seq`` per key and the newest time stamped (ns), kept across everything."""

    seqs: dict[str, int] = field(default_factory=dict)
    hlc_ns: int = 0

    def merge(self, other: SeqMarks) -> None:
        for k, s in other.seqs.items():
            if s > self.seqs.get(k, -1):
                self.seqs[k] = s
        self.hlc_ns = max(self.hlc_ns, other.hlc_ns)


def marks_path(path: Path) -> Path:
    return path.with_name(path.name + MARKS_SUFFIX)


def read_marks(path: Path) -> SeqMarks:
    """The copy of the marks beside the database (empty when missing or unreadable)."""
    try:
        doc = json.loads(marks_path(path).read_text(encoding="utf-8"))
        seqs = {str(k): int(v) for k, v in doc.get("seqs", {}).items()}
        return SeqMarks(seqs, int(doc.get("hlc_ns", 0)))
    except (OSError, ValueError, TypeError, AttributeError):
        return SeqMarks()


def write_marks(path: Path, marks: SeqMarks, fsync: bool) -> None:
    """Replace the copy of the marks atomically (a temporary file renamed over it)."""
    target = marks_path(path)
    tmp = target.with_name(target.name + ".tmp")
    data = json.dumps({"seqs": marks.seqs, "hlc_ns": marks.hlc_ns}, separators=(",", ":"))
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(data)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, target)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def salvage_marks(path: Path) -> SeqMarks:
    """What can still be read of a damaged database's marks (best effort: nothing raises)."""
    out = SeqMarks()
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=1.0)
    except sqlite3.Error:
        return out
    try:
        for query in (
            "SELECT key, seq FROM marks",
            "SELECT key, MAX(seq) FROM entries WHERE seq IS NOT NULL GROUP BY key",
        ):
            with contextlib.suppress(sqlite3.Error, ValueError, TypeError):
                out.merge(SeqMarks({str(k): int(s) for k, s in con.execute(query) if s is not None}))
        with contextlib.suppress(sqlite3.Error, ValueError, TypeError):
            row = con.execute("SELECT value FROM meta WHERE name = 'hlc_ns'").fetchone()
            if row is not None:
                out.hlc_ns = max(out.hlc_ns, int(row[0]))
    finally:
        con.close()
    return out


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
