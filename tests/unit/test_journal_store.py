"""The journal's storage (canopen_gateway.journal.store) on a real SQLite file in a temporary
directory: write ahead, group commit, seq across reopen, value windows, bounds, drops on a full
disk, damaged files set aside, and the path check."""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time

from canopen_gateway.journal import Entry, Journal, ntp64_of_time, path_problem
from canopen_gateway.journal.db import SCHEMA_VERSION
from canopen_gateway.journal.files import FILE_NAME
from tests.helpers import wait_until_sync

T0 = time.time() - 86400.0  # a day ago: within keep_days, not ahead of the clock


def ev(i: int, key: str = "p/n1/emcy", kind: str = "emcy", t0: float = T0) -> Entry:
    return Entry(ntp64_of_time(t0 + i), kind, key, "n1", i, json.dumps({"seq": i}).encode())


def started(tmp_path, **kw) -> Journal:
    j = Journal(tmp_path / "j", **kw)
    j.start()
    return j


def test_tickets_are_done_after_their_commit_in_order(tmp_path):
    j = Journal(tmp_path / "j", values_ms=0)
    seen: list[tuple[int, int]] = []
    lock = threading.Lock()

    def done(i: int) -> None:
        # once its ticket is done, the entry is in the journal (write ahead)
        rows = [r.seq for r in j.read(["p/n1/emcy"])]
        with lock:
            seen.append((i, rows[-1] if rows else 0))

    # the first half waits in the queue before the writer starts (one group for certain), the
    # second half is appended while the writer runs
    tickets = []
    for i in range(1, 301):
        if i == 151:
            j.start()
        tickets.append(j.append(ev(i)))
        j.when_done(tickets[-1], lambda i=i: done(i))
    assert j.wait(tickets[-1], 10)
    wait_until_sync(lambda: len(seen) == 300, what="300 callbacks")
    j.stop()
    assert tickets == list(range(1, 301))
    assert [i for i, _ in seen] == list(range(1, 301))
    assert all(last >= i for i, last in seen)
    assert j.counts.written == 300 and j.counts.dropped == 0
    assert j.counts.commits < 300  # grouped


def test_seq_per_key_survives_a_reopen(tmp_path):
    j = started(tmp_path, values_ms=0)
    for i in range(1, 6):
        j.append(ev(i))
    j.append(ev(3, key="p/n1/state", kind="state"))
    j.stop()
    again = Journal(tmp_path / "j")
    again.open()
    assert again.last_seqs() == {"p/n1/emcy": 5, "p/n1/state": 3}
    again.stop()


def test_values_keep_the_latest_sample_of_each_window(tmp_path):
    j = Journal(tmp_path / "j", values_ms=3_600_000)  # one window for the whole test
    j.start()
    for i in range(1, 101):
        j.value(ev(i, key="p/n1/value/position", kind="value"))
    j.value(ev(7, key="p/n1/value/speed", kind="value"))
    j.stop()  # the current window is committed at stop
    rows = list(Journal(tmp_path / "j").read(kinds=["value"]))
    assert sorted((r.key, r.seq) for r in rows) == [
        ("p/n1/value/position", 100),
        ("p/n1/value/speed", 7),
    ]


def test_read_is_in_time_order_with_bounds_and_chunks(tmp_path):
    j = started(tmp_path, values_ms=0)
    for i in (5, 1, 4, 2, 3):
        j.append(ev(i))
    j.stop()
    r = Journal(tmp_path / "j")
    assert [x.seq for x in r.read(chunk=2)] == [1, 2, 3, 4, 5]
    lo, hi = ntp64_of_time(T0 + 2), ntp64_of_time(T0 + 4)
    assert [x.seq for x in r.read(t_from=lo, t_to=hi, chunk=1)] == [2, 3, 4]
    assert [x.seq for x in r.read(t_from=lo + 1, t_to=hi - 1)] == [3]


def test_size_stays_bounded_under_a_flood(tmp_path):
    j = started(tmp_path, values_ms=0, max_mb=0.5)
    blob = b"x" * 200
    for i in range(20_000):
        j.append(Entry(ntp64_of_time(T0 + i), "emcy", "p/n1/emcy", "n1", i, blob))
    wait_until_sync(lambda: j.counts.written == 20_000, timeout_s=60, what="flood written")
    j.stop()
    size = (tmp_path / "j" / FILE_NAME).stat().st_size
    assert size <= 0.5 * 1024 * 1024 * 1.25
    assert j.counts.removed > 0
    seqs = [r.seq for r in Journal(tmp_path / "j").read()]
    assert seqs[-1] == 19_999 and seqs == sorted(seqs)  # the oldest went first
    assert len(seqs) == 20_000 - j.counts.removed


def test_a_full_database_trims_the_oldest_and_goes_on_journaling(tmp_path, caplog):
    j = Journal(tmp_path / "j", values_ms=0)
    j.open()
    j.disk.con.execute("PRAGMA max_page_count=48")  # SQLite's own "database or disk is full"
    j.start()
    last = 0
    for i in range(1, 2001):
        last = j.append(Entry(ntp64_of_time(T0 + i), "emcy", "k", "n1", i, b"y" * 500)) or last
        if i % 200 == 0:
            assert j.wait(last, 10)
    assert j.wait(last, 10)
    status = j.status()
    assert j.counts.written == 2000 and j.counts.dropped == 0 and j.counts.removed > 0
    assert status["disk_full"] and "disk full" in status["error"] and status["journaling"]
    seqs = [r.seq for r in j.read()]
    assert seqs[-1] == 2000 and seqs == list(range(seqs[0], 2001))  # the oldest went first
    j.stop()
    again = Journal(tmp_path / "j")
    again.open()
    assert again.last_seqs() == {"k": 2000}  # trimming removes rows, never the marks
    again.stop()


def test_a_slow_writer_drops_new_entries_but_keeps_their_order(tmp_path):
    j = Journal(tmp_path / "j", values_ms=0, max_pending=3)
    j.open()  # not started: nothing is written yet
    tickets = [j.append(ev(i)) for i in range(1, 7)]
    assert tickets == [1, 2, 3, 0, 0, 0] and j.counts.dropped == 3  # nothing of them is kept
    j.start()
    assert j.wait(3, 10)
    j.stop()
    assert [r.seq for r in Journal(tmp_path / "j").read()] == [1, 2, 3]
    again = Journal(tmp_path / "j")
    again.open()
    assert again.last_seqs() == {"p/n1/emcy": 6}  # a dropped entry's seq is never used again
    again.stop()


def _other_schema(path):
    path.unlink()
    con = sqlite3.connect(path)
    con.execute("CREATE TABLE something(x)")
    con.execute(f"PRAGMA user_version={SCHEMA_VERSION + 1}")
    con.commit()
    con.close()


DAMAGES = {
    "garbage": lambda path: path.write_bytes(b"this is no database" * 100),
    "truncated": lambda path: path.write_bytes(path.read_bytes()[:1500]),
    "schema": _other_schema,
}


def test_a_damaged_journal_is_set_aside_and_a_fresh_one_starts(tmp_path, caplog):
    for name, damage in DAMAGES.items():
        d = tmp_path / name
        j = started(d, values_ms=0)
        for i in range(1, 50):
            j.append(ev(i))
        j.stop()
        path = d / "j" / FILE_NAME
        damage(path)
        before = path.read_bytes()
        caplog.clear()
        fresh = Journal(d / "j")
        fresh.open()
        assert fresh.set_aside is not None and fresh.set_aside.read_bytes() == before, name
        assert list(fresh.read()) == [] and fresh.last_seqs() == {"p/n1/emcy": 49}
        lines = [r.getMessage() for r in caplog.records if "is damaged" in r.getMessage()]
        assert len(lines) == 1 and str(path) in lines[0] and str(fresh.set_aside) in lines[0]
        fresh.stop()


def test_entries_older_than_keep_days_go(tmp_path):
    now = [1.8e9]
    j = Journal(tmp_path / "j", values_ms=0, keep_days=1, clock=lambda: now[0])
    j.start()
    for i in range(10):
        j.append(ev(i * 3600, t0=1.8e9))  # one an hour
    wait_until_sync(lambda: j.counts.written == 10, what="written")
    now[0] = 1.8e9 + 86400 + 4.5 * 3600  # hours 0..4 are older than a day
    j.disk.next_keep = 0.0
    j.append(ev(100_000, t0=1.8e9))
    wait_until_sync(lambda: j.counts.written == 11, what="written")
    j.stop()
    assert j.counts.removed == 5
    assert [r.seq for r in Journal(tmp_path / "j").read()][0] == 5 * 3600


def test_expired_entries_go_at_start_in_chunks_without_any_new_entry(tmp_path):
    j = Journal(tmp_path / "j", values_ms=0, keep_days=10)  # keep_days lowered at the restart
    j.start()
    old = time.time() - 3 * 86400
    last = 0
    for i in range(5000):  # more than one chunk of expired entries
        last = j.append(ev(i, t0=old))
    j.append(ev(1, t0=time.time() - 3600))  # within keep_days
    assert j.wait(last + 1, 20)
    j.stop()
    again = Journal(tmp_path / "j", values_ms=0, keep_days=1)
    again.start()  # nothing is appended: the writer's first steps remove them
    wait_until_sync(lambda: again.counts.removed == 5000, timeout_s=20, what="expired removed")
    again.stop()
    assert [r.seq for r in Journal(tmp_path / "j").read()] == [1]


def test_path_problem_names_the_reason(tmp_path):
    assert path_problem(tmp_path / "new" / "dir") is None
    (tmp_path / "file").write_text("")
    why = path_problem(tmp_path / "file" / "journal")
    assert why is not None and "Not a directory" in why


def test_sync_full_makes_every_commit_fsync(tmp_path):
    for sync, level in (("normal", 1), ("full", 2)):
        j = Journal(tmp_path / sync, sync=sync)
        j.open()
        assert j.disk.con.execute("PRAGMA synchronous").fetchone()[0] == level
        assert j.disk.con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        j.stop()


def test_damaged_files_set_aside_are_pruned_by_age_and_count(tmp_path):
    d = tmp_path / "j"
    d.mkdir()
    now = time.time()
    for i, age_days in enumerate((0.1, 0.2, 0.3, 0.4, 40.0)):  # five set aside, one very old
        p = d / f"{FILE_NAME}.damaged-2026010{i}T000000Z"
        p.write_bytes(b"x")
        (d / f"{p.name}-wal").write_bytes(b"w")
        os.utime(p, (now - age_days * 86400, now - age_days * 86400))
    j = Journal(d, keep_days=30)
    j.open()
    j.stop()
    left = sorted(p.name for p in d.iterdir() if ".damaged-" in p.name)
    assert left == [f"{FILE_NAME}.damaged-2026010{i}T000000Z{s}" for i in range(3) for s in ("", "-wal")]


def test_a_version_1_journal_is_upgraded_in_place_with_its_seq_marks(tmp_path):
    d = tmp_path / "j"
    d.mkdir()
    con = sqlite3.connect(d / FILE_NAME)
    con.executescript(
        "CREATE TABLE entries(id INTEGER PRIMARY KEY, t INTEGER NOT NULL, kind TEXT NOT NULL,"
        " key TEXT NOT NULL, node TEXT, seq INTEGER, payload BLOB NOT NULL, tid BLOB);"
        "CREATE INDEX entries_key_t ON entries(key, t); CREATE INDEX entries_t ON entries(t);"
        "PRAGMA user_version=1;"
    )
    for i in range(1, 8):
        e = ev(i)
        con.execute("INSERT INTO entries(t, kind, key, node, seq, payload) VALUES (?, ?, ?, ?, ?, ?)",
                    (e.stamp - (1 << 63), e.kind, e.key, e.node, e.seq, e.payload))  # fmt: skip
    con.commit()
    con.close()
    j = Journal(d, values_ms=0)
    j.open()
    assert j.set_aside is None and j.last_seqs() == {"p/n1/emcy": 7}
    assert j.disk.con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION
    j.stop()
    assert [r.seq for r in Journal(d).read()] == list(range(1, 8))
