"""The ``_time`` selector argument as Zenoh storages take it, parsed into NTP64 bounds.

Grammar (Zenoh's time DSL)::

    range     := ldel [start] ".." [end] rdel      # an empty bound is open
    duration  := ldel start ";" span rdel          # start .. start + span
    ldel      := "[" (inclusive) | "]" (exclusive)
    rdel      := "]" (inclusive) | "[" (exclusive)
    start/end := "now(" ["-"] [span] ")" | an RFC 3339 / ISO 8601 instant (UTC when no offset)
    span      := number unit, unit one of u ms s m h d w

``now`` is resolved when the query is answered (the caller's ``now``). Every error names what
is wrong and what is allowed (``TimeRangeError``, answered as a ``reply_err``).

Imports: the standard library and journal.store (NTP64). Pure: no I/O.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import UTC, datetime

from gateway.journal.store import ntp64_of_time

UNITS_S = {"u": 1e-6, "ms": 1e-3, "s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0, "w": 604800.0}
_SPAN = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*(u|ms|s|m|h|d|w)\s*$")
_NOW = re.compile(r"^\s*now\(\s*(-?)\s*([^)]*)\)\s*$")
ALLOWED = (
    "[<from>..<to>] or [<from>;<duration>] (']' / '[' for exclusive bounds), each bound "
    "now(), now(-5m), an RFC 3339 time (2026-11-29T05:00:00Z) or empty; units u ms s m h d w"
)


class TimeRangeError(ValueError):
    """A ``_time`` value this gateway cannot read."""


@dataclass(frozen=True)
class TimeRange:
    """NTP64 bounds (None: open); ``*_excl``: the bound itself is outside."""

    start: int | None
    end: int | None
    start_excl: bool = False
    end_excl: bool = False

    def contains(self, t: int) -> bool:
        if self.start is not None and (t < self.start or (self.start_excl and t == self.start)):
            return False
        return not (self.end is not None and (t > self.end or (self.end_excl and t == self.end)))


def parse_span(text: str) -> float:
    """A duration in seconds (``5m``, ``1.5h``, ``200ms``)."""
    m = _SPAN.match(text)
    if m is None:
        raise TimeRangeError(
            f"_time: {text!r} is not a duration (a number and one of u ms s m h d w, e.g. 5m)"
        )
    return float(m.group(1)) * UNITS_S[m.group(2)]


def parse_instant(text: str, now: float) -> float:
    """A bound in seconds since 1970 (UTC)."""
    m = _NOW.match(text)
    if m is not None:
        sign, span = m.groups()
        offset = parse_span(span) if span.strip() else 0.0
        return now - offset if sign else now + offset
    t = text.strip()
    try:
        dt = datetime.fromisoformat(t[:-1] + "+00:00" if t.endswith(("Z", "z")) else t)
    except ValueError:
        raise TimeRangeError(f"_time: {text!r} is not a time; allowed: {ALLOWED}") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


def parse_time_range(text: str, now: float) -> TimeRange:
    """``text`` the ``_time`` value, ``now`` seconds since 1970 (resolves ``now(...)``)."""
    s = text.strip()
    if len(s) < 4 or s[0] not in "[]" or s[-1] not in "[]":
        raise TimeRangeError(f"_time: {text!r}: expected {ALLOWED}")
    start_excl, end_excl = s[0] == "]", s[-1] == "["
    body = s[1:-1]
    if ".." in body:
        a, b = body.split("..", 1)
        start = parse_instant(a, now) if a.strip() else None
        end = parse_instant(b, now) if b.strip() else None
    elif ";" in body:
        a, b = body.split(";", 1)
        if not a.strip():
            raise TimeRangeError(f"_time: {text!r}: the duration form needs a start")
        start = parse_instant(a, now)
        end = start + parse_span(b)
    else:
        raise TimeRangeError(f"_time: {text!r}: expected {ALLOWED}")
    for v in (start, end):
        if v is not None and not math.isfinite(v):
            raise TimeRangeError(f"_time: {text!r}: a bound is not a finite time")
    # nothing is older than 1970 or newer than 2106 (NTP64's end): such bounds are open ends
    start = None if start is not None and start < 0 else start
    end = None if end is not None and end >= 2**32 else end
    if start is not None and end is not None and start > end:
        raise TimeRangeError(f"_time: {text!r}: the start is after the end")
    return TimeRange(
        None if start is None else ntp64_of_time(start),
        None if end is None else ntp64_of_time(end),
        start_excl,
        end_excl,
    )
