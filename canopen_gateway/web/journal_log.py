"""The web console's journal: the events page's history from the store and forward journal
(``canopen_gateway.journal``), which survives restarts, and its exports of a time range.

=====================================  ==========================================================
``GET /api/journal``                   journal entries in time order: ``?from=`` and ``?to=``
                                       (``now(-1h)``, ``now(-30)``, an RFC 3339 time; empty:
                                       open; default the last hour), ``?node=``,
                                       ``?kind=state,emcy,audit``; at most ``MAX_ROWS``
                                       (``truncated`` says so); 409 when the gateway has no
                                       journal
``GET /api/journal.csv``               the same range as CSV (time, kind, node, key, seq,
                                       text, payload), every row, streamed
``GET /api/journal.json``              the same range as a JSON array of entries (with their
                                       payload), every row, streamed
=====================================  ==========================================================

Each entry gets a line of text in the words of the live event log (``text_of``). The reading is
done in a worker thread (``asyncio.to_thread``), never on the event loop. An export is an
HTTP/1.1 chunked answer (``http.server.Chunked``): a chunk of ``EXPORT_CHUNK`` rows read and
formatted in a worker thread, then written, then the next after a turn on the loop
(``runtime.turns``: the PLC first), so that memory stays constant whatever the range and a
Modbus request never waits for an export. Bad parameters get a 400 with the words of what is
allowed.

Imports: http.server (request/response types), journal (the store and the time grammar),
runtime.turns. Never bus/, modbus/ or zenoh_bridge/.
"""

from __future__ import annotations

import asyncio
import csv
import io
import itertools
import json
import time
from collections.abc import AsyncIterator, Callable, Iterable, Iterator
from datetime import UTC, datetime
from http import HTTPStatus
from typing import Any

from canopen_gateway.http.server import JSON_TYPE, Chunked, Request, Response
from canopen_gateway.journal import (
    Journal,
    Row,
    TimeRangeError,
    ntp64_of_ns,
    parse_instant_ns,
    time_of_ntp64,
)
from canopen_gateway.journal.clock import NANOS
from canopen_gateway.runtime.turns import LoopTurns

JOURNAL_KINDS = ("state", "emcy", "audit")
MAX_ROWS = 2000  # per JSON answer
EXPORT_CHUNK = 200  # rows per chunk of an export
DEFAULT_SPAN_S = 3600.0
CSV_HEADER = ["time", "kind", "node", "key", "seq", "text", "payload"]


def text_of(row: Row) -> str:
    """An entry in one line, as the live event log words it."""
    try:
        doc = json.loads(row.payload)
    except ValueError:
        return row.payload.decode(errors="replace")
    node = row.node or ""
    if row.kind == "emcy":
        return f"{node}: EMCY {doc.get('code')} {doc.get('text') or ''}".rstrip()
    if row.kind == "state":
        words = [f"NMT state {doc.get('nmt_state')}", f"lifecycle {doc.get('lifecycle')}"]
        if "alive" in doc:
            words.insert(0, "alive" if doc["alive"] else "lost")
        return f"{node}: " + ", ".join(words)
    if row.kind == "audit":  # the parts it has: a login names no node, a refusal no value
        parts = [str(p) for p in (doc.get("op"), node, doc.get("what")) if p]
        value = f" = {json.dumps(doc['value'])}" if doc.get("value") is not None else ""
        return f"{doc.get('who')}: {' '.join(parts)}{value}: {doc.get('outcome')}"
    return json.dumps(doc)


def _iso(t: int) -> str:
    return datetime.fromtimestamp(time_of_ntp64(t), UTC).isoformat(timespec="milliseconds")


def _bad(message: str) -> Response:
    body = json.dumps({"error": "bad_request", "message": message}).encode()
    return Response(HTTPStatus.BAD_REQUEST, body, JSON_TYPE)


class JournalLog:
    """The routes of the module docstring over one journal (None: none configured)."""

    def __init__(
        self,
        journal: Journal | None,
        nodes: Iterable[str],
        *,
        clock: Callable[[], float] = time.time,
        headers: dict[str, str] | None = None,
        turns: LoopTurns | None = None,
    ):
        self.journal = journal
        self.nodes = frozenset(nodes)
        self.clock = clock
        self.headers = headers or {}
        self.turns = turns

    async def answer(self, request: Request, path: str) -> Response | Chunked | None:
        if path not in ("/api/journal", "/api/journal.csv", "/api/journal.json"):
            return None
        if self.journal is None:
            body = {"error": "no_journal", "message": "no journal: set journal.path"}
            return Response(HTTPStatus.CONFLICT, json.dumps(body).encode(), JSON_TYPE)
        query = self._query(request)
        if isinstance(query, Response):
            return query
        if path.endswith(".csv"):
            headers = {**self.headers, "Content-Disposition": 'attachment; filename="journal.csv"'}
            return Chunked("text/csv; charset=utf-8", self._export(query, _csv_chunk, True), headers)
        if path.endswith(".json"):
            headers = {**self.headers, "Content-Disposition": 'attachment; filename="journal.json"'}
            return Chunked(JSON_TYPE, self._export(query, _json_chunk, False), headers)
        rows = await asyncio.to_thread(self._rows, query, MAX_ROWS + 1)
        doc = {
            "kinds": list(JOURNAL_KINDS),
            "entries": [self._doc(r) for r in rows[:MAX_ROWS]],
            "truncated": len(rows) > MAX_ROWS,
        }
        return Response(HTTPStatus.OK, json.dumps(doc).encode(), JSON_TYPE, headers=self.headers)

    def _query(self, request: Request) -> dict[str, Any] | Response:
        q = request.query
        now = round(self.clock() * NANOS)
        bounds: dict[str, int | None] = {}
        for name, default in (("from", now - round(DEFAULT_SPAN_S * NANOS)), ("to", None)):
            try:  # the words of one instant: from= and to= take no bracketed range
                bounds[name] = parse_instant_ns(q[name], now) if q.get(name) else default
            except TimeRangeError as exc:
                return _bad(str(exc).replace("_time", name, 1))
        node = q.get("node") or None
        if node is not None and node not in self.nodes:
            return _bad(f"node: no node named {node!r}; nodes: {', '.join(sorted(self.nodes))}")
        kinds = q["kind"].split(",") if q.get("kind") else list(JOURNAL_KINDS)
        wrong = [k for k in kinds if k not in JOURNAL_KINDS]
        if wrong:
            return _bad(f"kind: {', '.join(wrong)} is not one of {', '.join(JOURNAL_KINDS)}")
        t_from, t_to = bounds["from"], bounds["to"]
        return {
            "t_from": None if t_from is None else ntp64_of_ns(max(t_from, 0)),
            "t_to": None if t_to is None else ntp64_of_ns(max(t_to, 0)),
            "node": node,
            "kinds": kinds,
        }

    def _rows(self, query: dict[str, Any], limit: int) -> list[Row]:
        assert self.journal is not None
        return list(itertools.islice(self.journal.read(**query), limit))

    @staticmethod
    def _doc(r: Row) -> dict[str, Any]:
        return {
            "ts": time_of_ntp64(r.t),
            "kind": r.kind,
            "node": r.node,
            "key": r.key,
            "seq": r.seq,
            "text": text_of(r),
        }

    async def _export(
        self, query: dict[str, Any], chunk: Callable[[list[Row], bool], bytes], csv_head: bool
    ) -> AsyncIterator[bytes]:
        """The chunks of an export: ``EXPORT_CHUNK`` rows read and formatted in a worker
        thread, a turn on the loop before each."""
        assert self.journal is not None
        rows: Iterator[Row] = self.journal.read(**query)
        first = True

        def next_chunk() -> bytes | None:
            nonlocal first
            part = list(itertools.islice(rows, EXPORT_CHUNK))
            if not part and not first:
                return None
            data = chunk(part, first)
            first = False
            return data

        try:
            while True:
                if self.turns is not None:
                    await self.turns.turn(bounded=False)
                data = await asyncio.to_thread(next_chunk)
                if data is None:
                    break
                yield data
            if not csv_head:
                yield b"]\n"
        finally:
            close = getattr(rows, "close", None)
            if close is not None:
                await asyncio.to_thread(close)


def _csv_chunk(rows: list[Row], first: bool) -> bytes:
    out = io.StringIO()
    w = csv.writer(out)
    if first:
        w.writerow(CSV_HEADER)
    for r in rows:
        payload = r.payload.decode(errors="replace")
        w.writerow([_iso(r.t), r.kind, r.node or "", r.key, r.seq or "", text_of(r), payload])
    return out.getvalue().encode()


def _json_chunk(rows: list[Row], first: bool) -> bytes:
    parts = []
    for r in rows:
        try:
            payload: Any = json.loads(r.payload)
        except ValueError:
            payload = r.payload.decode(errors="replace")
        doc = {**JournalLog._doc(r), "time": _iso(r.t), "payload": payload}
        parts.append(json.dumps(doc))
    body = ",\n".join(parts)
    if first:
        return ("[\n" + body).encode()
    return (",\n" + body).encode() if body else b""
