"""The ``_time`` grammar of Zenoh storages (gateway.journal.timerange): every bound form, open
ends, exclusive delimiters, the duration form, and errors that name what is wrong; with
hypothesis over instants and spans."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.journal import TimeRangeError, ntp64_of_time, parse_time_range
from gateway.journal.timerange import UNITS_S, parse_span

NOW = 1_800_000_000.0

instants = st.datetimes(
    min_value=datetime(1971, 1, 1), max_value=datetime(2100, 1, 1), timezones=st.just(UTC)
)
spans = st.tuples(st.integers(0, 1_000), st.sampled_from(sorted(UNITS_S)))  # within NTP64


def close(ntp: int | None, seconds: float) -> bool:
    return ntp is not None and abs(ntp - ntp64_of_time(seconds)) <= 2**32 // 1_000_000


@given(instants, instants, st.booleans(), st.booleans())
def test_rfc3339_bounds_in_either_delimiter(a, b, lex, rex):
    lo, hi = sorted((a, b))
    text = f"{']' if lex else '['}{lo.isoformat().replace('+00:00', 'Z')}..{hi.isoformat()}{'[' if rex else ']'}"
    tr = parse_time_range(text, NOW)
    assert close(tr.start, lo.timestamp()) and close(tr.end, hi.timestamp())
    assert (tr.start_excl, tr.end_excl) == (lex, rex)


@given(spans, spans)
def test_now_offsets(past, future):
    (n1, u1), (n2, u2) = past, future
    tr = parse_time_range(f"[now(-{n1}{u1})..now({n2}{u2})]", NOW)
    assert close(tr.start, NOW - n1 * UNITS_S[u1]) and close(tr.end, NOW + n2 * UNITS_S[u2])


@given(instants, spans)
def test_the_duration_form_is_start_plus_span(start, span):
    n, unit = span
    tr = parse_time_range(f"[{start.isoformat()};{n}{unit}]", NOW)
    end = start.timestamp() + n * UNITS_S[unit]
    assert tr.end is None if end >= 2**32 else close(tr.end, end)


@given(instants, st.integers(0, 2**32 - 1))
def test_contains_respects_exclusive_bounds(at, frac):
    t = ntp64_of_time(at.timestamp())
    inclusive = parse_time_range(f"[{at.isoformat()}..{at.isoformat()}]", NOW)
    exclusive = parse_time_range(f"]{at.isoformat()}..{at.isoformat()}[", NOW)
    assert inclusive.contains(inclusive.start) and not exclusive.contains(exclusive.start)
    assert abs(inclusive.start - t) <= 2**32 // 1_000_000


@given(st.text(max_size=30))
def test_anything_else_is_refused_with_words_or_parsed(text):
    try:
        tr = parse_time_range(text, NOW)
    except TimeRangeError as exc:
        assert str(exc).startswith("_time:")
    else:
        assert tr.start is None or tr.end is None or tr.start <= tr.end


def test_open_ends_and_naive_times_are_utc():
    assert parse_time_range("[..]", NOW).start is None
    tr = parse_time_range("[2026-11-29 05:00:00..]", NOW)
    assert close(tr.start, datetime(2026, 11, 29, 5, tzinfo=UTC).timestamp()) and tr.end is None
    assert close(parse_time_range("[now()..]", NOW).start, NOW)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("now(-5m)", "expected ["),
        ("[now(-5x)..]", "not a duration"),
        ("[tomorrow..]", "not a time"),
        ("[now()..now(-1h)]", "start is after the end"),
        ("[;5m]", "needs a start"),
    ],
)
def test_errors_name_what_is_wrong(text, words):
    with pytest.raises(TimeRangeError, match=words.replace("[", r"\[")):
        parse_time_range(text, NOW)


def test_bounds_beyond_ntp64_are_open_ends():
    assert parse_time_range("[1900-01-01T00:00:00Z..now(1000w)]", NOW).start is None
    assert parse_time_range("[..now(10000w)]", NOW).end is None


def test_spans():
    assert parse_span("1.5h") == 5400.0 and parse_span("200ms") == pytest.approx(0.2)
    assert parse_span("3w") == timedelta(weeks=3).total_seconds()
