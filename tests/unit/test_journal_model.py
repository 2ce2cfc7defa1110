"""History answers against a model of the journal (hypothesis, a rule-based state machine):
random entries on a few keys (times that also go back, as a pair member's heard samples may),
restarts, expiry (``keep_days`` on an injected clock) and ``_time`` ranges of every form (to
the nanosecond, exclusive, open, ``now(...)``) on exact keys and wildcards, read with the
default page and with pages of 2 rows: every answer equals the model's, in (time, order of
arrival) order, and every key's highest ``seq`` survives restarts and expiry."""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from datetime import UTC, datetime
from pathlib import Path

from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule

from canopen_gateway.journal import Entry, Journal, ntp64_of_ns, parse_time_range
from canopen_gateway.zenoh_bridge.history import HistoryService

NANOS = 10**9
P = "p"
KEYS = [f"{P}/n1/emcy", f"{P}/n1/state", f"{P}/n2/emcy", f"{P}/n1/value/x"]
AUDIT = f"{P}/audit"
PATTERNS = [*KEYS, AUDIT, f"{P}/*/emcy", f"{P}/n1/**", f"{P}/**", f"{P}/n3/emcy"]
KEEP_DAYS = 1.0
T0 = 1_700_000_000 * NANOS  # the model's first time (ns)


def matches(pattern: str, key: str) -> bool:
    """Key expression matching, written apart from Zenoh's: * one chunk, ** any number."""
    if pattern == AUDIT or key == AUDIT:
        return pattern == key  # the audit answers only to its own name
    rx = "/".join("[^/]+" if c == "*" else ".*" if c == "**" else re.escape(c) for c in pattern.split("/"))
    return re.fullmatch(rx.replace("/.*", "(/.*)?"), key) is not None


def rfc3339(ns: int) -> str:
    secs, sub = divmod(ns, NANOS)
    return datetime.fromtimestamp(secs, UTC).strftime("%Y-%m-%dT%H:%M:%S") + f".{sub:09d}Z"


class JournalModel(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.dir = Path(tempfile.mkdtemp(prefix="journal-model-"))
        self.now_s = T0 / NANOS + 3600.0  # the journal's wall clock (seconds)
        self.rows: list[tuple[int, int, str, int | None]] = []  # (t ns, arrival, key, seq)
        self.arrivals = 0
        self.highest: dict[str, int] = {}
        self.t = T0
        self.journal = self.start()

    def start(self) -> Journal:
        j = Journal(self.dir, values_ms=0, keep_days=KEEP_DAYS, clock=lambda: self.now_s)
        j.start()
        return j

    def teardown(self) -> None:
        self.journal.stop()
        shutil.rmtree(self.dir, ignore_errors=True)

    @rule(key=st.sampled_from([*KEYS, AUDIT]), steps=st.lists(st.integers(-3, 40), min_size=1, max_size=5))
    def append(self, key: str, steps: list[int]) -> None:
        ticket = 0
        for step in steps:  # nanoseconds apart, sometimes back, sometimes the same time
            self.t += step
            seq = None if key == AUDIT else self.highest.get(key, 0) + 1
            if seq is not None:
                self.highest[key] = seq
            kind = "audit" if key == AUDIT else key.split("/")[2]
            ticket = self.journal.append(Entry(ntp64_of_ns(self.t), kind, key, "n1", seq, json.dumps({"seq": seq}).encode()))
            self.rows.append((self.t, self.arrivals, key, seq))
            self.arrivals += 1
        assert ticket and self.journal.wait(ticket, 10)

    def expire(self, before: int) -> None:
        """The model's side of the writer's upkeep: what ``keep_days`` left behind goes; wait
        for the writer to have looked (its first step after a start, or after the clock)."""
        cutoff = round((self.now_s - KEEP_DAYS * 86400.0) * NANOS)
        expired = [r for r in self.rows if r[0] < cutoff]
        self.rows = [r for r in self.rows if r[0] >= cutoff]
        deadline = 2000
        while self.journal.disk.next_keep == 0.0:
            deadline -= 1
            assert deadline, "the writer's upkeep did not run"
            self.journal.wait(1 << 62, 0.005)
        assert self.journal.counts.removed == before + len(expired)

    @rule()
    def restart(self) -> None:
        self.journal.stop()
        self.journal = self.start()  # its first step removes what expired meanwhile
        assert self.journal.last_seqs() == self.highest
        self.expire(0)

    @rule(hours=st.integers(1, 30))
    def time_passes(self, hours: int) -> None:
        self.now_s += hours * 3600.0
        before = self.journal.counts.removed
        self.journal.upkeep_now()
        self.expire(before)

    @rule(
        pattern=st.sampled_from(PATTERNS),
        lo=st.none() | st.tuples(st.integers(0, 10**6), st.integers(-1, 1)),
        hi=st.none() | st.tuples(st.integers(0, 10**6), st.integers(-1, 1)),
        lex=st.booleans(),
        rex=st.booleans(),
        ago=st.none() | st.integers(0, 200_000),
    )
    def query(self, pattern, lo, hi, lex, rex, ago) -> None:
        def bound(b: tuple[int, int] | None) -> str:
            if b is None or not self.rows:
                return ""
            row = self.rows[b[0] % len(self.rows)]
            return rfc3339(row[0] + b[1])  # a row's time, or a nanosecond beside it

        start = f"now(-{ago}s)" if ago is not None else bound(lo)
        text = f"{']' if lex else '['}{start}..{bound(hi)}{'[' if rex else ']'}"
        now_ns = round(self.now_s * NANOS)
        try:
            tr = parse_time_range(text, now_ns)
        except ValueError:
            return  # the start after the end: refused, as the parser's own tests hold
        want = [
            (key, seq)
            for t, _arrival, key, seq in sorted(self.rows)
            if matches(pattern, key) and tr.contains_ns(t)
        ]
        service = HistoryService(self.journal, P, KEYS, b"\x01" * 16, clock_ns=lambda: now_ns)
        assert [(r.key, r.seq) for r in service.rows(pattern, text)] == want, text
        keys = service.matching(pattern)
        if keys:
            t_from, t_to = tr.ntp64_bounds()
            paged = self.journal.read(keys, t_from=t_from, t_to=t_to, chunk=2)
            assert [(r.key, r.seq) for r in paged] == want, (text, "pages of 2")

    @invariant()
    def marks_never_go_back(self) -> None:
        seen = self.journal.last_seqs()
        assert all(seen.get(k, 0) >= s for k, s in self.highest.items())


JournalModel.TestCase.settings = settings(max_examples=20, stateful_step_count=25, deadline=None)
test_history_answers_equal_the_model = JournalModel.TestCase
