"""History by time range: ``get <key>?_time=[<from>..<to>]`` answered from the journal, as a
Zenoh storage answers it.

Keys with a history: ``<prefix>/<node>/state``, ``<prefix>/<node>/emcy``,
``<prefix>/<node>/value/<signal>`` (at ``journal.values_ms`` resolution, ``publish: pdo``
signals too) and ``<prefix>/audit`` (the audit of writes, JSON). A key expression with
wildcards gets the history of every such key it matches, merged in time order; the audit is
answered only to a query that names it exactly (``<prefix>/audit``), so a router's access rule
on that key holds against a wildcard. A key without history answers nothing (an empty answer,
as a storage that holds no such key). The time range is Zenoh's (``journal.timerange``, to the
nanosecond); ``now`` is this gateway's clock when the query is answered.

One reply per entry, in the journal's order (its times: the gateway's hybrid clock, which
never goes back, so within a key the order of ``seq``, across restarts and clock steps): the
payload as published (with its ``seq``) and its timestamp (an event's as published; a value's
and an audit entry's as journaled, with this gateway's id). Replies are produced lazily (an
iterator over rows read a page at a time, resumed after the last row read), so an answer of
any length never sits in memory; ``stamped_replies`` hands them to the queries' worker
(``zenoh_bridge/worker.py``), which sends them in a lane of their own, in turns beside every
other query, never on the event loop. A getter gives up at its timeout and Zenoh does not tell
the queryable: an answer stops after ``ANSWER_LIMIT_S`` (Zenoh's default get timeout) with a
``reply_err`` ``cut`` saying where to resume (``AnswerCut``). A selector this gateway cannot
read raises ``ValueError`` naming what is wrong (answered ``reply_err``).

Imports: zenoh, journal, northbound.keys. Nothing of bus/ or modbus/.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, NamedTuple

import zenoh

from canopen_gateway.journal import Journal, Row, ns_of_ntp64, parse_time_range
from canopen_gateway.journal.clock import NANOS
from canopen_gateway.northbound.keys import audit_key

TIME_PARAM = "_time"
#: an answer stops after this long: Zenoh's default get timeout (``queries_default_timeout``)
ANSWER_LIMIT_S = 10.0


class Stamped(NamedTuple):
    """A journaled sample as replied: the payload as published and its timestamp."""

    payload: bytes
    timestamp: zenoh.Timestamp


class AnswerCut(Exception):
    """A history answer stopped at its time limit: where the rest starts."""

    def __init__(self, key: str, after_ns: int, limit_s: float) -> None:
        self.resume = rfc3339_ns(after_ns)
        super().__init__(
            f"answer stopped after {limit_s:g} s (the default timeout of a Zenoh get): ask "
            f"{key}?_time=]{self.resume}..] for the rest"
        )

    def body(self, key: str) -> dict[str, Any]:
        return {"error": "cut", "message": str(self), "key": key, "resume": self.resume}


def rfc3339_ns(ns: int) -> str:
    """Nanoseconds since 1970 as RFC 3339 in UTC, to the nanosecond."""
    secs, sub = divmod(ns, NANOS)
    return datetime.fromtimestamp(secs, UTC).strftime("%Y-%m-%dT%H:%M:%S") + f".{sub:09d}Z"


def has_time_range(query: zenoh.Query) -> bool:
    return query.parameters.get(TIME_PARAM) is not None


def zenoh_timestamp(t: int, tid: bytes | None, fallback_id: bytes) -> zenoh.Timestamp:
    """A Zenoh timestamp from a journaled NTP64 time and id (exact: the nanoseconds are
    rounded as Zenoh rounds them back)."""
    nanos = ((t & 0xFFFFFFFF) * 1_000_000_000 + (1 << 31)) >> 32
    return zenoh.Timestamp(zenoh.NTP64(t >> 32, nanos), tid or fallback_id)


@dataclass
class HistoryService:
    journal: Journal
    prefix: str
    #: the keys the journal keeps a history of (events and values; the audit besides)
    keys: Collection[str]
    #: the id of this gateway's timestamps (entries journaled without one)
    own_id: bytes
    clock_ns: Callable[[], int] = time.time_ns
    clock: Callable[[], float] = time.monotonic
    limit_s: float = ANSWER_LIMIT_S

    def matching(self, key: str) -> list[str]:
        """The journaled keys a query key (expression) names; the audit only by its name."""
        audit = audit_key(self.prefix)
        if key == audit or key in self.keys:
            return [key]
        try:
            ke = zenoh.KeyExpr(key)
        except zenoh.ZError:
            return []
        return [k for k in self.keys if ke.intersects(zenoh.KeyExpr(k))]

    def rows(self, key: str, time_param: str) -> Iterator[Row]:
        """The journal's rows of the range, in order, read lazily; a bad selector raises here,
        at the call; a key without history gives none."""
        tr = parse_time_range(time_param, self.clock_ns())
        keys = self.matching(key)
        if not keys:
            return iter(())
        lo, hi = tr.ntp64_bounds()
        return self.journal.read(keys, t_from=lo, t_to=hi)

    def stamped_replies(self, query: zenoh.Query, key: str) -> Iterator[tuple[str, Stamped]]:
        """Every entry of the query's range as the queries' worker sends it, a reply per step:
        its key and its payload with its timestamp; after ``limit_s``, ``AnswerCut``. A bad
        range is refused before any reply."""
        rows = self.rows(key, query.parameters.get(TIME_PARAM) or "")
        return self._until_cut(key, rows, self.clock() + self.limit_s)

    def _until_cut(self, key: str, rows: Iterator[Row], deadline: float) -> Iterator[tuple[str, Stamped]]:
        for r in rows:
            if self.clock() > deadline:
                raise AnswerCut(key, ns_of_ntp64(r.t) - 1, self.limit_s)
            yield r.key, Stamped(r.payload, zenoh_timestamp(r.t, r.tid, self.own_id))
