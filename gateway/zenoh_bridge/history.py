"""History by time range: ``get <key>?_time=[<from>..<to>]`` answered from the journal.

Keys with a history: ``<prefix>/<node>/state``, ``<prefix>/<node>/emcy``,
``<prefix>/<node>/value/<signal>`` (at ``journal.values_ms`` resolution) and ``<prefix>/audit``
(the audit of writes, JSON). A key expression with wildcards gets the history of every such key
it matches, merged in time order. The time range is Zenoh's (``journal.timerange``); ``now`` is
this gateway's clock when the query is answered.

One reply per entry, in time order: the payload as published (with its ``seq``) and the
original Zenoh timestamp (an audit entry: its time, with this session's id). Replies are
produced lazily (``rows``: an iterator over rows read from SQLite a chunk at a time), so an
answer of any length never sits in memory; ``stamped_replies`` hands them to the queries'
worker (``zenoh_bridge/worker.py``), which sends them in turns beside every other query and
never on the event loop (reading the disk takes time). A selector this gateway cannot read, or a
key without history, raises ``ValueError`` naming what is wrong (answered ``reply_err``).

Imports: zenoh, journal, northbound.keys. Nothing of bus/ or modbus/.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass
from typing import NamedTuple

import zenoh

from gateway.journal import Journal, Row, parse_time_range
from gateway.northbound.keys import audit_key

TIME_PARAM = "_time"


class Stamped(NamedTuple):
    """A journaled sample as replied: the payload as published and its original timestamp."""

    payload: bytes
    timestamp: zenoh.Timestamp


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
    #: the keys the bridge publishes events and values on (history is kept for those)
    keys: Collection[str]
    session: Callable[[], zenoh.Session | None]
    clock: Callable[[], float] = time.time

    def matching(self, key: str) -> list[str]:
        """The journaled keys a query key (expression) names."""
        known = [*self.keys, audit_key(self.prefix)]
        if key in known:
            return [key]
        try:
            ke = zenoh.KeyExpr(key)
        except zenoh.ZError:
            return []
        return [k for k in known if ke.intersects(zenoh.KeyExpr(k))]

    def rows(self, key: str, time_param: str) -> Iterator[Row]:
        """The journal's rows of the range, in time order, read lazily; a bad selector or a key
        without history raises here, at the call."""
        tr = parse_time_range(time_param, self.clock())
        keys = self.matching(key)
        if not keys:
            raise ValueError(
                f"{key}: no history here; kept for {self.prefix}/<node>/state, "
                f"{self.prefix}/<node>/emcy, {self.prefix}/<node>/value/<signal> and "
                f"{audit_key(self.prefix)}"
            )
        return self.journal.read(
            keys,
            t_from=tr.start,
            t_to=tr.end,
            from_open=tr.start_excl,
            to_open=tr.end_excl,
        )

    def stamped_replies(self, query: zenoh.Query, key: str) -> Iterator[tuple[str, Stamped]]:
        """Every entry of the query's range as the queries' worker sends it, a reply per step
        (``zenoh_bridge/worker.py``: in turns, giving way to the event loop): its key and
        its payload with its original timestamp. A bad range is refused before any reply."""
        rows = self.rows(key, query.parameters.get(TIME_PARAM) or "")
        s = self.session()
        own_id = bytes(s.new_timestamp().get_id()) if s is not None else bytes(16)
        return ((r.key, Stamped(r.payload, zenoh_timestamp(r.t, r.tid, own_id))) for r in rows)
