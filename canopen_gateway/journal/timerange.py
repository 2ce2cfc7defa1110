"""The ``_time`` selector argument as Zenoh storages take it, parsed into bounds in nanoseconds.

Grammar (Zenoh's time DSL, ``zenoh-util`` ``time_range.rs``)::

    range     := ldel [start] ".." [end] rdel      # an empty bound is open
    duration  := ldel start ";" span rdel          # start .. start + span (see below)
    ldel      := "[" (inclusive) | "]" (exclusive)
    rdel      := "]" (inclusive) | "[" (exclusive)
    start/end := "now(" ["-" | "+"] [span] ")" | an RFC 3339 instant (UTC when no offset)
    span      := number [unit], unit one of u ms s m h d w; a number alone is seconds;
                 a number as Zenoh reads one (``30``, ``1.5``, ``.5``, ``1e3``, ``+5``)

Instants are read to the nanosecond (``2026-11-29T05:00:00.123456789Z``), the precision of a
Zenoh timestamp, so ``[t..t]`` finds the sample stamped ``t``. ``now`` is resolved when the
query is answered (the caller's ``now_ns``). Zenoh separates selector parameters with ``;``,
so the duration form cannot travel in a selector: it is read (a caller may pass it whole) but
never suggested. Every error names what is wrong and what is allowed (``TimeRangeError``,
answered as a ``reply_err``).

Imports: the standard library and journal.clock (NTP64). Pure: no I/O.
"""

from __future__ import annotations

import calendar
import math
import re
from dataclasses import dataclass

from canopen_gateway.journal.clock import NANOS, ntp64_of_ns

UNITS_S = {"u": 1e-6, "ms": 1e-3, "s": 1.0, "m": 60.0, "h": 3600.0, "d": 86400.0, "w": 604800.0}
_NUMBER = r"\+?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
_SPAN = re.compile(rf"^\s*({_NUMBER})\s*(u|ms|s|m|h|d|w)?\s*$")
_NOW = re.compile(r"^\s*now\(\s*(-?)\s*([^)]*)\)\s*$")
_INSTANT = re.compile(
    r"^\s*([0-9]{4})-([0-9]{2})-([0-9]{2})[Tt ]([0-9]{2}):([0-9]{2}):([0-9]{2})"
    r"(?:[.,]([0-9]{1,9}))?\s*(Z|z|[+-][0-9]{2}:?[0-9]{2})?\s*$"
)
#: the forms of one bound, in words (the console's ``from=``/``to=`` take these too)
INSTANTS = (
    "now(), now(-5m), now(-30) (seconds), or an RFC 3339 time (2026-11-29T05:00:00Z, to the "
    "nanosecond, UTC when it has no offset)"
)
ALLOWED = (
    f"[<from>..<to>] (']' at the start or '[' at the end for an exclusive bound), each bound "
    f"{INSTANTS} or empty (open), durations in u ms s m h d w"
)
#: instants outside NTP64 (before 1970, after 2106) are open ends
_NTP64_END_NS = (1 << 32) * NANOS


class TimeRangeError(ValueError):
    """A ``_time`` value (or a bound) this gateway cannot read."""


@dataclass(frozen=True)
class TimeRange:
    """Bounds in nanoseconds since 1970 (None: open); ``*_excl``: the bound itself is out."""

    start_ns: int | None
    end_ns: int | None
    start_excl: bool = False
    end_excl: bool = False

    def ntp64_bounds(self) -> tuple[int | None, int | None]:
        """The inclusive NTP64 bounds of the range (for times made of whole nanoseconds, as
        every stamp of this gateway is: exact)."""
        lo = None if self.start_ns is None else ntp64_of_ns(self.start_ns + self.start_excl)
        hi = None if self.end_ns is None else ntp64_of_ns(self.end_ns - self.end_excl)
        return lo, hi

    def contains_ns(self, ns: int) -> bool:
        if self.start_ns is not None and (ns < self.start_ns or (self.start_excl and ns == self.start_ns)):
            return False
        return not (self.end_ns is not None and (ns > self.end_ns or (self.end_excl and ns == self.end_ns)))


def parse_span(text: str) -> float:
    """A duration in seconds, as Zenoh reads one (``5m``, ``1.5h``, ``200ms``, ``30``, ``1e3s``)."""
    m = _SPAN.match(text)
    if m is None:
        raise TimeRangeError(
            f"_time: {text!r} is not a duration (a number and one of u ms s m h d w, or a "
            "number of seconds: 5m, 30, 1e3s)"
        )
    value = float(m.group(1)) * UNITS_S[m.group(2) or "s"]
    if not math.isfinite(value):
        raise TimeRangeError(f"_time: {text!r} is not a finite duration")
    return value


def _rfc3339_ns(text: str) -> int | None:
    m = _INSTANT.match(text)
    if m is None:
        return None
    y, mo, d, h, mi, s = (int(g) for g in m.groups()[:6])
    frac, zone = m.group(7) or "", m.group(8)
    try:
        secs = calendar.timegm((y, mo, d, h, mi, s, 0, 0, 0))
        if not (1 <= mo <= 12 and 1 <= d <= calendar.monthrange(y, mo)[1] and h < 24 and mi < 60 and s < 61):
            return None
    except (ValueError, OverflowError):
        return None
    ns = secs * NANOS + int(frac.ljust(9, "0"))
    if zone and zone not in ("Z", "z"):
        sign = -1 if zone[0] == "-" else 1
        digits = zone[1:].replace(":", "")
        ns -= sign * (int(digits[:2]) * 3600 + int(digits[2:]) * 60) * NANOS
    return ns


def parse_instant_ns(text: str, now_ns: int) -> int:
    """One bound in nanoseconds since 1970 (UTC)."""
    m = _NOW.match(text)
    if m is not None:
        sign, span = m.groups()
        offset = parse_span(span) if span.strip() else 0.0
        return now_ns + round((-offset if sign else offset) * NANOS)
    ns = _rfc3339_ns(text)
    if ns is None:
        raise TimeRangeError(f"_time: {text!r} is not a time; allowed: {INSTANTS}")
    return ns


def parse_instant(text: str, now: float) -> float:
    """One bound in seconds since 1970 (UTC)."""
    return parse_instant_ns(text, round(now * NANOS)) / NANOS


def parse_time_range(text: str, now_ns: int) -> TimeRange:
    """``text`` the ``_time`` value, ``now_ns`` nanoseconds since 1970 (resolves ``now(...)``)."""
    s = text.strip()
    if len(s) < 4 or s[0] not in "[]" or s[-1] not in "[]":
        raise TimeRangeError(f"_time: {text!r}: expected {ALLOWED}")
    start_excl, end_excl = s[0] == "]", s[-1] == "["
    body = s[1:-1]
    if ".." in body:
        a, b = body.split("..", 1)
        start = parse_instant_ns(a, now_ns) if a.strip() else None
        end = parse_instant_ns(b, now_ns) if b.strip() else None
    elif ";" in body:  # whole, as a caller may pass it (a Zenoh selector cannot carry it)
        a, b = body.split(";", 1)
        if not a.strip():
            raise TimeRangeError(f"_time: {text!r}: expected {ALLOWED}")
        start = parse_instant_ns(a, now_ns)
        end = start + round(parse_span(b) * NANOS)
    else:
        raise TimeRangeError(f"_time: {text!r}: expected {ALLOWED}")
    # nothing is older than 1970 or newer than 2106 (NTP64's end): such bounds are open ends
    start = None if start is not None and start < 0 else start
    end = None if end is not None and end >= _NTP64_END_NS else end
    if start is not None and end is not None and start > end:
        raise TimeRangeError(f"_time: {text!r}: the start is after the end")
    return TimeRange(start, end, start_excl, end_excl)
