"""The journal's SQLite database: its schema (versioned; version 1 is migrated in place), the
connection's settings, one commit (room made, rows inserted, marks kept), the bounded steps of
upkeep (expired rows, WAL checkpoints) and the reading of rows in time order.

Rules held here:

* **Times** are NTP64 (journal.clock), stored with ``T_BIAS`` subtracted so that they fit
  SQLite's signed integers in order; rows are read in (time, id) order.
* **Marks**: each commit raises ``marks`` (the highest ``seq`` per key) and ``meta.hlc_ns``
  (the newest time stamped) in its own transaction; trimming deletes rows, never marks.
* **Bounded work per step**: a commit deletes at most ``TRIM_ROUNDS`` x ``TRIM_CHUNK`` of the
  oldest rows to make room; expired rows go ``TRIM_CHUNK`` at a time, one chunk per step of the
  writer; reading pages by key set (the last row's (time, id)), each page one short read
  transaction (no reader holds a snapshot for long: the WAL can be checkpointed), a key at a
  time merged in time order when several keys are read.

Imports: the standard library, journal.clock, journal.files. Never zenoh nor an adapter.
"""

from __future__ import annotations

import heapq
import sqlite3
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, NamedTuple

from canopen_gateway.journal.clock import NTP64_MAX, ns_of_ntp64
from canopen_gateway.journal.files import SeqMarks

SCHEMA_VERSION = 2
KNOWN_VERSIONS = (1, 2)
T_BIAS = 1 << 63  # NTP64 is unsigned; SQLite integers are signed
READ_CHUNK = 500  # rows per page of a read
TRIM_CHUNK = 2000  # rows deleted at most per DELETE
TRIM_ROUNDS = 4  # DELETEs at most per commit to make room
ROW_OVERHEAD = 80  # bytes of a row and its index entries besides payload and key (estimate)
COLUMNS = "id, t, kind, key, node, seq, payload, tid"

TABLES = """
CREATE TABLE IF NOT EXISTS entries(
  id INTEGER PRIMARY KEY,
  t INTEGER NOT NULL,
  kind TEXT NOT NULL,
  key TEXT NOT NULL,
  node TEXT,
  seq INTEGER,
  payload BLOB NOT NULL,
  tid BLOB
);
CREATE INDEX IF NOT EXISTS entries_key_t ON entries(key, t);
CREATE INDEX IF NOT EXISTS entries_t ON entries(t);
CREATE TABLE IF NOT EXISTS marks(key TEXT PRIMARY KEY, seq INTEGER NOT NULL) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS meta(name TEXT PRIMARY KEY, value INTEGER NOT NULL) WITHOUT ROWID;
"""
#: a few pages of each b-tree of the entries: what ``files.damage`` reads of an existing file
CHECKS = (
    f"SELECT {COLUMNS} FROM entries ORDER BY id DESC LIMIT 1",
    "SELECT t FROM entries INDEXED BY entries_t ORDER BY t DESC LIMIT 1",
    "SELECT key, t FROM entries INDEXED BY entries_key_t ORDER BY key DESC, t DESC LIMIT 1",
)
INSERT = "INSERT INTO entries(t, kind, key, node, seq, payload, tid) VALUES (?, ?, ?, ?, ?, ?, ?)"
RAISE_MARK = (
    "INSERT INTO marks(key, seq) VALUES (?, ?) "
    "ON CONFLICT(key) DO UPDATE SET seq = excluded.seq WHERE excluded.seq > marks.seq"
)
RAISE_META = (
    "INSERT INTO meta(name, value) VALUES (?, ?) "
    "ON CONFLICT(name) DO UPDATE SET value = excluded.value WHERE excluded.value > meta.value"
)


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


#: a row as inserted: (t - T_BIAS, kind, key, node, seq, payload, tid)
DbRow = tuple[int, str, str, str | None, int | None, bytes, bytes | None]


def connect(path: Path, sync: str, wal_bytes: int) -> sqlite3.Connection:
    """The writer's connection, in WAL mode, the schema made or migrated to this version."""
    con = sqlite3.connect(path, check_same_thread=False, isolation_level=None, timeout=5.0)
    con.execute("PRAGMA journal_mode=WAL")
    con.execute(f"PRAGMA synchronous={'FULL' if sync == 'full' else 'NORMAL'}")
    set_wal_bound(con, wal_bytes)
    version = con.execute("PRAGMA user_version").fetchone()[0]
    if version != SCHEMA_VERSION:
        script = TABLES
        if version == 1:  # the marks a version 1 journal kept only in its rows
            script += (
                "INSERT OR IGNORE INTO marks(key, seq) SELECT key, MAX(seq) FROM entries "
                "WHERE seq IS NOT NULL GROUP BY key;\n"
            )
        con.executescript(f"BEGIN IMMEDIATE;\n{script}PRAGMA user_version={SCHEMA_VERSION};\nCOMMIT;")
    return con


def set_wal_bound(con: sqlite3.Connection, wal_bytes: int) -> None:
    page = con.execute("PRAGMA page_size").fetchone()[0]
    con.execute(f"PRAGMA wal_autocheckpoint={max(16, wal_bytes // page)}")
    con.execute(f"PRAGMA journal_size_limit={wal_bytes}")


def load_marks(con: sqlite3.Connection) -> SeqMarks:
    seqs = {k: int(s) for k, s in con.execute("SELECT key, seq FROM marks")}
    row = con.execute("SELECT value FROM meta WHERE name = 'hlc_ns'").fetchone()
    top = con.execute("SELECT MAX(t) FROM entries").fetchone()[0]  # the last of an index
    hlc = max(int(row[0]) if row else 0, ns_of_ntp64(top + T_BIAS) if top is not None else 0)
    return SeqMarks(seqs, hlc)


def save_marks(con: sqlite3.Connection, marks: SeqMarks) -> None:
    """Marks known from elsewhere (a damaged file's, the copy beside it) into this database."""
    con.execute("BEGIN IMMEDIATE")
    con.executemany(RAISE_MARK, list(marks.seqs.items()))
    con.execute(RAISE_META, ("hlc_ns", marks.hlc_ns))
    con.execute("COMMIT")


def live_bytes(con: sqlite3.Connection) -> int:
    page = con.execute("PRAGMA page_size").fetchone()[0]
    count = con.execute("PRAGMA page_count").fetchone()[0]
    free = con.execute("PRAGMA freelist_count").fetchone()[0]
    return int((count - free) * page)


def delete_oldest(con: sqlite3.Connection, n: int) -> int:
    return con.execute(
        "DELETE FROM entries WHERE id IN (SELECT id FROM entries ORDER BY id LIMIT ?)", (n,)
    ).rowcount


def make_room(con: sqlite3.Connection, incoming: int, per_row: int, budget: int) -> int:
    """Inside a transaction: the oldest rows go until the live pages and ``incoming`` bytes fit
    in 90 % of ``budget`` (checked only when they would pass ``budget``); at most
    ``TRIM_ROUNDS`` deletes of ``TRIM_CHUNK`` rows. Returns the rows removed."""
    if live_bytes(con) + incoming <= budget:
        return 0
    removed = 0
    for _ in range(TRIM_ROUNDS):
        excess = live_bytes(con) + incoming - 0.9 * budget
        if excess <= 0:
            break
        n = min(TRIM_CHUNK, max(100, int(excess // max(per_row, 1))))
        got = delete_oldest(con, n)
        removed += got
        if not got:
            break
    return removed


def commit(
    con: sqlite3.Connection, rows: list[DbRow], marks: dict[str, int], hlc_ns: int, budget: int
) -> int:
    """One transaction: room made (``make_room``), the rows inserted, the marks raised.
    Returns the rows removed to make room. Raises what SQLite raises (rolled back)."""
    incoming = sum(len(r[5]) + len(r[2]) + ROW_OVERHEAD for r in rows)
    try:
        con.execute("BEGIN IMMEDIATE")
        removed = make_room(con, incoming, incoming // max(len(rows), 1), budget)
        con.executemany(INSERT, rows)
        if marks:
            con.executemany(RAISE_MARK, list(marks.items()))
        con.execute(RAISE_META, ("hlc_ns", hlc_ns))
        con.execute("COMMIT")
    except BaseException:
        if con.in_transaction:
            con.execute("ROLLBACK")
        raise
    return removed


def delete_expired(con: sqlite3.Connection, before_ntp64: int) -> int:
    """One chunk of the rows older than ``before_ntp64`` (a whole chunk: more may remain)."""
    return con.execute(
        "DELETE FROM entries WHERE id IN (SELECT id FROM entries INDEXED BY entries_t "
        "WHERE t < ? ORDER BY t LIMIT ?)",
        (before_ntp64 - T_BIAS, TRIM_CHUNK),
    ).rowcount


def checkpoint(con: sqlite3.Connection, truncate: bool) -> None:
    """Copy the WAL into the database (``truncate``: and empty the WAL file, waiting at most
    ``busy_timeout`` for readers)."""
    con.execute(f"PRAGMA wal_checkpoint({'TRUNCATE' if truncate else 'PASSIVE'})").fetchall()


def _where(
    kinds: Iterable[str] | None, node: str | None, lo: int | None, hi: int | None
) -> tuple[list[str], list[Any]]:
    where: list[str] = []
    args: list[Any] = []
    if kinds is not None:
        kl = list(kinds)
        where.append(f"kind IN ({','.join('?' * len(kl))})")
        args += kl
    if node is not None:
        where.append("node = ?")
        args.append(node)
    if hi is not None:
        where.append("t <= ?")
        args.append(min(hi, NTP64_MAX) - T_BIAS)
    return where, args


def _pages(
    con: sqlite3.Connection, base: str, args: list[Any], lo: int | None, chunk: int
) -> Iterator[Row]:
    """The rows of ``base`` (a SELECT with a WHERE) from ``lo`` on, a page at a time, each page
    resumed after the last row's (t, id): linear in the rows read, whatever the range."""
    last = (-T_BIAS if lo is None else lo - T_BIAS, -1)  # ids start at 1
    while True:
        rows = con.execute(
            base + " AND (t, id) > (?, ?) ORDER BY t, id LIMIT ?", (*args, *last, chunk)
        ).fetchall()
        for r in rows:
            yield Row(r[0], r[1] + T_BIAS, *r[2:])
        if len(rows) < chunk:
            return
        last = (rows[-1][1], rows[-1][0])


def read(
    path: Path,
    keys: Iterable[str] | None,
    kinds: Iterable[str] | None,
    node: str | None,
    lo: int | None,
    hi: int | None,
    chunk: int = READ_CHUNK,
) -> Iterator[Row]:
    """Rows in (time, id) order between the inclusive NTP64 bounds ``lo`` / ``hi`` (None:
    open), on a read-only connection of the reader's own; several keys read a key at a time
    and merged."""
    uri = f"{path.resolve().as_uri()}?mode=ro"  # percent-encoded: any file name
    con = sqlite3.connect(uri, uri=True, check_same_thread=False, timeout=5.0)
    try:
        where, args = _where(kinds, node, lo, hi)
        select = f"SELECT {COLUMNS} FROM entries"
        if keys is None:
            base = f"{select} INDEXED BY entries_t WHERE " + " AND ".join([*where, "1"])
            yield from _pages(con, base, args, lo, chunk)
            return
        ks = sorted(set(keys))
        each = max(50, chunk // max(len(ks), 1))
        streams = [
            _pages(con, f"{select} WHERE " + " AND ".join(["key = ?", *where]), [k, *args], lo, each)
            for k in ks
        ]
        yield from heapq.merge(*streams, key=lambda r: (r.t, r.id))
    finally:
        con.close()
