"""The ``_time`` grammar of Zenoh storages (canopen_gateway.journal.timerange): every bound form Zenoh
accepts (``now(-30)``, ``now(+5m)``, ``1e3s``...), instants to the nanosecond (``[t..t]`` finds
t), open ends, exclusive delimiters, and errors that name what is wrong and suggest only forms
that can travel in a Zenoh selector; with hypothesis over instants and spans."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st

from canopen_gateway.journal import TimeRangeError, ns_of_ntp64, ntp64_of_ns, parse_time_range
from canopen_gateway.journal.timerange import UNITS_S, parse_instant_ns, parse_span

NOW = 1_800_000_000 * 10**9 + 123_456_789

instants = st.datetimes(
    min_value=datetime(1971, 1, 1), max_value=datetime(2100, 1, 1), timezones=st.just(UTC)
)
spans = st.tuples(st.integers(0, 1_000), st.sampled_from(sorted(UNITS_S)))  # within NTP64


def rfc3339(ns: int) -> str:
    secs, sub = divmod(ns, 10**9)
    return datetime.fromtimestamp(secs, UTC).strftime("%Y-%m-%dT%H:%M:%S") + f".{sub:09d}Z"


@given(instants, instants, st.booleans(), st.booleans())
def test_rfc3339_bounds_in_either_delimiter(a, b, lex, rex):
    lo, hi = sorted((a, b))
    text = f"{']' if lex else '['}{lo.isoformat().replace('+00:00', 'Z')}..{hi.isoformat()}{'[' if rex else ']'}"
    tr = parse_time_range(text, NOW)
    assert tr.start_ns == round(lo.timestamp() * 10**6) * 1000
    assert tr.end_ns == round(hi.timestamp() * 10**6) * 1000
    assert (tr.start_excl, tr.end_excl) == (lex, rex)


@given(st.integers(0, 2**32 * 10**9 - 1))
def test_an_instant_to_the_nanosecond_finds_the_sample_stamped_with_it(ns):
    """A Zenoh timestamp made of nanoseconds, written in RFC 3339 to the nanosecond, bounds a
    range that holds exactly that sample: [t..t] gets t, ]t..] and [..t[ do not."""
    t = ntp64_of_ns(ns)
    assert ns_of_ntp64(t) == ns
    text = rfc3339(ns)
    lo, hi = parse_time_range(f"[{text}..{text}]", NOW).ntp64_bounds()
    assert lo == hi == t
    lo, _ = parse_time_range(f"]{text}..]", NOW).ntp64_bounds()
    _, hi = parse_time_range(f"[..{text}[", NOW).ntp64_bounds()
    assert lo is not None and hi is not None and lo > t > hi


@given(spans, spans)
def test_now_offsets(past, future):
    (n1, u1), (n2, u2) = past, future
    tr = parse_time_range(f"[now(-{n1}{u1})..now({n2}{u2})]", NOW)
    assert tr.start_ns == NOW - round(n1 * UNITS_S[u1] * 10**9)
    assert tr.end_ns == NOW + round(n2 * UNITS_S[u2] * 10**9)


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("now(-30)", -30), ("now(+5m)", 300), ("now(-1e3s)", -1000), ("now(1.5)", 1.5),
     ("now(-.5h)", -1800), ("now()", 0), ("now(-2w)", -2 * 604800), ("now(-250u)", -250e-6)],
)  # fmt: skip
def test_the_duration_forms_zenoh_accepts(text, seconds):
    assert parse_instant_ns(text, NOW) == NOW + round(seconds * 10**9)


@given(instants, spans)
def test_the_duration_form_is_start_plus_span_when_passed_whole(start, span):
    n, unit = span
    tr = parse_time_range(f"[{start.isoformat()};{n}{unit}]", NOW)
    end = round(start.timestamp() * 10**6) * 1000 + round(n * UNITS_S[unit] * 10**9)
    assert tr.end_ns is None if end >= 2**32 * 10**9 else tr.end_ns == end


@given(st.text(max_size=30))
def test_anything_else_is_refused_with_words_or_parsed(text):
    try:
        tr = parse_time_range(text, NOW)
    except TimeRangeError as exc:
        assert str(exc).startswith("_time:")
        assert ";" not in str(exc).split("expected", 1)[-1]  # never the form a selector cuts
    else:
        assert tr.start_ns is None or tr.end_ns is None or tr.start_ns <= tr.end_ns


def test_open_ends_and_naive_times_are_utc():
    assert parse_time_range("[..]", NOW).start_ns is None
    tr = parse_time_range("[2026-11-29 05:00:00..]", NOW)
    assert tr.start_ns == int(datetime(2026, 11, 29, 5, tzinfo=UTC).timestamp()) * 10**9
    assert tr.end_ns is None
    assert parse_time_range("[now()..]", NOW).start_ns == NOW
    assert parse_instant_ns("2026-11-29T07:00:00+02:00", NOW) == tr.start_ns


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("now(-5m)", "expected ["),
        ("[now(-5x)..]", "not a duration"),
        ("[tomorrow..]", "not a time"),
        ("[now()..now(-1h)]", "start is after the end"),
        ("[;5m]", "expected ["),
        ("[now(-inf)..]", "not a duration"),
        ("[2026-02-30T00:00:00Z..]", "not a time"),
    ],
)
def test_errors_name_what_is_wrong(text, words):
    with pytest.raises(TimeRangeError, match=words.replace("[", r"\[")) as err:
        parse_time_range(text, NOW)
    assert "<duration>" not in str(err.value) and ";" not in str(err.value).split(": ", 2)[-1]


def test_bounds_beyond_ntp64_are_open_ends():
    assert parse_time_range("[1900-01-01T00:00:00Z..now(1000w)]", NOW).start_ns is None
    assert parse_time_range("[..now(10000w)]", NOW).end_ns is None


def test_spans():
    assert parse_span("1.5h") == 5400.0 and parse_span("200ms") == pytest.approx(0.2)
    assert parse_span("30") == 30.0 and parse_span("1e3s") == 1000.0 and parse_span("+5m") == 300
