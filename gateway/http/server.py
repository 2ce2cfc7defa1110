"""Health and metrics over HTTP: ``GET /healthz``, ``GET /livez``, ``GET /metrics``.

Responsible for: a minimal HTTP/1.1 server for probes and Prometheus scrapes, and the shape of
the health document (``build_status``; ``pair_status`` for the role and peer of a hot-standby
pair). It knows nothing of CAN, Modbus or Zenoh: the gateway
hands it a ``status_fn`` returning a dict and, optionally, a metrics registry.

- ``/healthz``: ``status_fn()`` as JSON; 200 when its ``"status"`` is ``"ready"``, else 503 (500
  if ``status_fn`` raises). For readiness probes, load balancers and HEALTHCHECK.
- ``/livez``: 200 as long as the event loop answers. For liveness probes: restarting the gateway
  does not fix a missing router or an unplugged bus, so liveness must not depend on them.
- ``/metrics``: ``prometheus_client.generate_latest(registry)`` in the text format.
- anything else 404; methods other than GET/HEAD 405. One request per connection
  (``Connection: close``).

Why ``asyncio.start_server`` and not ``http.server`` in a thread: the server runs on the
gateway's own event loop, so ``status_fn`` and the metrics collectors read the process image
on the thread that writes it, without locks; it starts and stops with the gateway and costs no
thread. The protocol needed is tiny (a request line, GET on three paths, a closed connection
after each answer), so a bounded hand-written parser is simpler than a dependency (aiohttp is
not one). Requests are bounded: 8 KiB of head, ``read_timeout_s`` to send it.

Other paths go to an optional ``app`` (the web console, ``gateway.web``): it gets a parsed
``Request`` (method, path, query, lower-case headers, a body of at most 64 KiB given by
Content-Length, the client's address and the local address the request arrived at) and returns
a ``Response``, a ``Stream`` (written until the stream ends or the client goes away: server-sent
events), a ``Chunked`` answer (HTTP/1.1 chunked encoding: each chunk written and drained before
the next is asked for, so an export of any length takes constant memory; the iterator closed
when the client goes away) or None (404). With ``turns`` (``turns.LoopTurns``: the
PLC first), each app request waits for its turn on the event loop before the app renders it;
when too many wait, it is answered 503 ``busy`` with ``Retry-After``. Without an app, or for the three paths
above, methods other than GET/HEAD are answered 405. The three paths above answer whatever the
``Host`` header (probes and scrapes name the address they reach); the app checks it. A
``Content-Length`` that is not ASCII digits, or given twice, and a ``Host`` given twice are
answered 400 (RFC 9112 6.3, 3.2), never an exception.

Config (section ``health:`` of the gateway config): ``host`` (127.0.0.1), ``port`` (0 = off).
Port 0 passed to ``HealthServer`` itself binds an ephemeral port (see ``.port``): the caller
decides that 0 in the config means "do not start one".

Imports: the standard library, prometheus_client and runtime.turns only.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import json
import logging
import urllib.parse
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from dataclasses import KW_ONLY, dataclass, field
from http import HTTPStatus
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from gateway.runtime.turns import ACCEPT_BACKLOG, RETRY_AFTER_S, LoopTurns

log = logging.getLogger("gateway.health")  # the name users see in log lines

StatusFn = Callable[[], Mapping[str, Any] | Awaitable[Mapping[str, Any]]]

READY = "ready"
NOT_READY = "not-ready"
MAX_REQUEST_HEAD_BYTES = 8192
MAX_REQUEST_BODY_BYTES = 65536
JSON_TYPE = "application/json"
TEXT_TYPE = "text/plain; charset=utf-8"
HEALTH_PATHS = ("/healthz", "/livez", "/metrics")
#: headers a request may carry once (RFC 9112 6.3: a repeated Content-Length is an error)
SINGLE_HEADERS = frozenset({"content-length", "host"})


@dataclass(frozen=True)
class Request:
    """One parsed request for an ``app``: header names lower-case, the first value of each
    query parameter."""

    method: str
    path: str
    query: Mapping[str, str] = field(default_factory=dict)
    headers: Mapping[str, str] = field(default_factory=dict)
    body: bytes = b""
    client: str = ""  # the peer's address (per-client limits of the app)
    local: str = ""  # the address the request arrived at (the app's Host check)


@dataclass(frozen=True)
class Response:
    status: HTTPStatus
    body: bytes = b""
    content_type: str = TEXT_TYPE
    headers: Mapping[str, str] = field(default_factory=dict)


def _error(path: str, status: HTTPStatus, kind: str, message: str) -> Response:
    """An error the server answers itself: under ``/api/`` a JSON document with ``error`` and
    ``message``, as the API's own errors; elsewhere one line of text."""
    if path.startswith("/api/"):
        body = json.dumps({"error": kind, "message": message}).encode() + b"\n"
        return Response(status, body, JSON_TYPE)
    return Response(status, message.encode() + b"\n", TEXT_TYPE)


StreamBody = Callable[[asyncio.StreamReader, asyncio.StreamWriter], Awaitable[None]]


@dataclass(frozen=True)
class Stream:
    """An answer without a length: the headers, then ``body(reader, writer)`` writes until it
    returns (e.g. the client went away); the connection is closed after."""

    content_type: str
    body: StreamBody
    headers: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Chunked:
    """An answer of unknown length in HTTP/1.1 chunked encoding: the headers, then each bytes
    ``chunks`` yields as one chunk (written and drained before the next is asked for), then the
    last chunk. The iterator is closed when the client goes away."""

    content_type: str
    chunks: AsyncIterator[bytes]
    headers: Mapping[str, str] = field(default_factory=dict)


App = Callable[[Request], Awaitable[Response | Stream | Chunked | None]]


def build_status(
    *,
    bus_open: bool,
    modbus_up: bool | None,
    zenoh_up: bool | None,
    nodes: Mapping[str, Mapping[str, Any]] | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The health document: ready when the CAN bus is open and every enabled adapter is up.

    ``modbus_up`` / ``zenoh_up`` are None when that adapter is disabled in the config. Node
    details are reported but do not decide readiness: a node that is off is a plant problem the
    gateway must report (over Modbus, Zenoh and here), not a reason to take the gateway away.
    ``reasons`` lists, in words, why the gateway is not ready.
    """
    reasons = []
    if not bus_open:
        reasons.append("CAN bus is not open")
    if modbus_up is False:
        reasons.append("Modbus TCP server is not serving")
    if zenoh_up is False:
        reasons.append("Zenoh session is not open")
    return {
        "status": NOT_READY if reasons else READY,
        "reasons": reasons,
        "bus_open": bus_open,
        "modbus_up": modbus_up,
        "zenoh_up": zenoh_up,
        "nodes": {name: dict(detail) for name, detail in (nodes or {}).items()},
        **extra,
    }


def pair_status(
    role: str | None,
    *,
    now_s: float,
    recent_s: float,
    claim: tuple[int, int, float] | None = None,
    peer_heartbeat_s: float | None = None,
    peer_node_id: int | None = None,
    master_id: int | None = None,
    conflict: str | None = None,
    peer_role: str = "unknown",
) -> dict[str, Any]:
    """The ``role`` and ``peer`` entries of /healthz: this gateway's role in a hot-standby pair
    and what it knows of the other gateway (both None outside a pair).

    ``role`` is this gateway's (active, standby, listening, negotiating, isolated, duplicate),
    ``master_id`` the pair id of the master heard active (a third-party CiA 302-2 master's
    too; None: unknown), ``conflict`` what a device with this gateway's own pair id was heard
    sending (None: nothing). The peer is known by what was heard of it, on the bus clock
    (``now_s``): ``peer_role`` its role as its own heartbeat says it (``active``, ``standby``,
    ``isolated``; ``unknown`` when not heard within ``recent_s``, the take-over time),
    ``claim`` its last active master response (priority, pair node id, time heard),
    ``peer_heartbeat_s`` when its own heartbeat (``master.redundancy.peer_node_id``) was last
    heard. A peer whose role is not heard but whose claim is younger than ``recent_s`` is
    ``active``; one whose heartbeat alone is that young ``standby``; else ``unknown``
    (``heard`` false: nothing of it in that time).
    """
    if role is None:
        return {"role": None, "peer": None}

    def age(at_s: float | None) -> float | None:
        return None if at_s is None else max(0.0, now_s - at_s)

    def shown(age_s: float | None) -> float | None:
        return None if age_s is None else round(age_s, 3)

    if claim is not None and peer_node_id is not None and claim[1] != peer_node_id:
        claim = None  # a third-party master's claim, not the peer's
    claim_age, hb_age = age(claim[2] if claim else None), age(peer_heartbeat_s)
    if peer_role == "unknown":
        if claim_age is not None and claim_age <= recent_s:
            peer_role = "active"
        elif hb_age is not None and hb_age <= recent_s:
            peer_role = "standby"
    return {
        "role": role,
        "master_id": master_id,
        "conflict": conflict,
        "peer": {
            "heard": peer_role != "unknown",
            "role": peer_role,
            "node_id": claim[1] if claim else peer_node_id,
            "priority": claim[0] if claim else None,
            "claim_age_s": shown(claim_age),
            "heartbeat_age_s": shown(hb_age),
        },
    }


@dataclass(eq=False, repr=False)
class HealthServer:
    """HTTP endpoint for probes and scrapes on the running event loop.

    Usage::

        server = HealthServer("127.0.0.1", 0, status_fn, registry=metrics.registry)
        await server.start()
        server.port          # the bound port, an ephemeral one when 0 was asked
        await server.stop()
    """

    host: str
    #: the port asked for; ``port`` is the one bound
    requested_port: int
    status_fn: StatusFn
    registry: CollectorRegistry | None = None
    _: KW_ONLY
    read_timeout_s: float = 5.0
    app: App | None = None
    #: the app's requests take turns on the event loop (the PLC first); None: they do not
    turns: LoopTurns | None = None
    _server: asyncio.Server | None = field(default=None, init=False)
    _connections: set[asyncio.Task[None]] = field(default_factory=set, init=False)

    @property
    def port(self) -> int:
        """The port actually bound (the ephemeral one when 0 was asked); 0 before ``start``."""
        if self._server is None or not self._server.sockets:
            return 0
        return self._server.sockets[0].getsockname()[1]

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    async def start(self) -> None:
        if self._server is not None:
            raise RuntimeError("health server already started")
        self._server = await asyncio.start_server(
            self._on_connection,
            self.host,
            self.requested_port,
            limit=MAX_REQUEST_HEAD_BYTES,
            backlog=ACCEPT_BACKLOG,
        )
        log.info(
            "health endpoint on %s (/healthz, /livez, /metrics%s)",
            self.url,
            ", web console /" if self.app is not None else "",
        )

    async def stop(self) -> None:
        """Stops listening and closes open connections; returns when they are gone."""
        server, self._server = self._server, None
        if server is None:
            return
        server.close()
        for task in list(self._connections):
            task.cancel()
        if self._connections:
            await asyncio.gather(*self._connections, return_exceptions=True)
        await server.wait_closed()

    async def _on_connection(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections.add(task)
        try:
            await self._serve_one(reader, writer)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass  # the client went away; nothing to answer
        except asyncio.CancelledError:
            # ``stop()`` ends open connections (e.g. event streams): end quietly, asyncio's
            # server would log a cancelled connection task as an error
            if self._server is not None:
                raise
        finally:
            self._connections.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    async def _serve_one(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            head = await asyncio.wait_for(
                reader.readuntil(b"\r\n\r\n"), timeout=self.read_timeout_s
            )
        except TimeoutError:
            return await self._respond(writer, HTTPStatus.REQUEST_TIMEOUT, b"", TEXT_TYPE)
        except asyncio.LimitOverrunError:
            return await self._respond(
                writer, HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE, b"", TEXT_TYPE
            )
        lines = head.decode("latin-1").split("\r\n")
        parts = lines[0].split()
        if len(parts) != 3 or not parts[2].startswith("HTTP/1."):
            return await self._respond(writer, HTTPStatus.BAD_REQUEST, b"bad request\n", TEXT_TYPE)
        method, target, _version = parts
        path, _, query = target.partition("?")
        head_only = method == "HEAD"
        if self.app is not None and path not in HEALTH_PATHS:
            return await self._serve_app(reader, writer, method, path, query, lines[1:])
        if method not in ("GET", "HEAD"):
            return await self._respond(
                writer,
                HTTPStatus.METHOD_NOT_ALLOWED,
                b"GET or HEAD only\n",
                TEXT_TYPE,
                extra_headers={"Allow": "GET, HEAD"},
            )
        if path == "/healthz":
            status, body = await self._health()
            return await self._respond(writer, status, body, JSON_TYPE, head_only=head_only)
        if path == "/livez":
            body = b'{"status": "alive"}\n'
            return await self._respond(writer, HTTPStatus.OK, body, JSON_TYPE, head_only=head_only)
        if path == "/metrics" and self.registry is not None:
            body = generate_latest(self.registry)
            return await self._respond(
                writer, HTTPStatus.OK, body, CONTENT_TYPE_LATEST, head_only=head_only
            )
        return await self._respond(
            writer, HTTPStatus.NOT_FOUND, b"not found\n", TEXT_TYPE, head_only=head_only
        )

    async def _serve_app(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        method: str,
        path: str,
        query: str,
        header_lines: list[str],
    ) -> None:
        assert self.app is not None
        headers, twice = _headers(header_lines)
        if twice is not None:
            return await self._refuse(
                writer, path, HTTPStatus.BAD_REQUEST, "bad_request", f"{twice} given twice"
            )
        if "transfer-encoding" in headers:
            return await self._refuse(
                writer, path, HTTPStatus.LENGTH_REQUIRED, "length_required", "send a Content-Length body"
            )
        length_text = headers.get("content-length", "0")
        if not (length_text.isascii() and length_text.isdigit()):
            return await self._refuse(
                writer, path, HTTPStatus.BAD_REQUEST, "bad_request", "bad Content-Length"
            )
        length = int(length_text)
        if length > MAX_REQUEST_BODY_BYTES:
            too_large = f"body larger than {MAX_REQUEST_BODY_BYTES} bytes"
            return await self._refuse(writer, path, HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "too_large", too_large)
        try:
            body = await asyncio.wait_for(reader.readexactly(length), self.read_timeout_s)
        except TimeoutError:
            return await self._refuse(
                writer, path, HTTPStatus.REQUEST_TIMEOUT, "timeout", "the body did not arrive in time"
            )
        request = Request(
            method=method,
            path=urllib.parse.unquote(path),
            query={k: v[0] for k, v in urllib.parse.parse_qs(query).items()},
            headers=headers,
            body=body,
            client=_peer(writer),
            local=_peer(writer, "sockname"),
        )
        try:
            if self.turns is None or await self.turns.turn():
                answer = await self.app(request)
            else:
                busy = _error(path, HTTPStatus.SERVICE_UNAVAILABLE, "busy",
                              "too many requests wait; ask again shortly")  # fmt: skip
                answer = Response(busy.status, busy.body, busy.content_type,
                                  {"Retry-After": str(RETRY_AFTER_S)})  # fmt: skip
        except Exception:
            log.exception("web request %s %s failed", method, path)
            answer = _error(path, HTTPStatus.INTERNAL_SERVER_ERROR, "internal", "internal error (see the log)")
        if answer is None:
            answer = _error(path, HTTPStatus.NOT_FOUND, "not_found", "not found")
        if isinstance(answer, Chunked):
            return await self._send_chunked(writer, answer, head_only=method == "HEAD")
        if isinstance(answer, Stream):
            writer.write(_stream_head(answer.content_type, answer.headers))
            await writer.drain()
            await answer.body(reader, writer)
            return
        await self._respond(
            writer,
            answer.status,
            answer.body,
            answer.content_type,
            head_only=method == "HEAD",
            extra_headers=answer.headers,
        )

    @staticmethod
    async def _send_chunked(writer: asyncio.StreamWriter, answer: Chunked, *, head_only: bool) -> None:
        chunks = answer.chunks
        try:
            headers = {"Transfer-Encoding": "chunked", **answer.headers}
            writer.write(_stream_head(answer.content_type, headers))
            await writer.drain()
            if head_only:
                return
            async for data in chunks:
                if data:
                    writer.write(b"%x\r\n%s\r\n" % (len(data), data))
                    await writer.drain()  # the client reads it: memory stays constant
            writer.write(b"0\r\n\r\n")
            await writer.drain()
        finally:
            aclose = getattr(chunks, "aclose", None)
            if aclose is not None:
                await aclose()

    async def _health(self) -> tuple[HTTPStatus, bytes]:
        try:
            status = self.status_fn()
            if inspect.isawaitable(status):
                status = await status
        except Exception as exc:
            log.exception("health status function failed")
            doc: Mapping[str, Any] = {"status": NOT_READY, "reasons": [f"status error: {exc!r}"]}
            return HTTPStatus.INTERNAL_SERVER_ERROR, _json(doc)
        code = HTTPStatus.OK if status.get("status") == READY else HTTPStatus.SERVICE_UNAVAILABLE
        return code, _json(status)

    async def _refuse(
        self, writer: asyncio.StreamWriter, path: str, status: HTTPStatus, kind: str, message: str
    ) -> None:
        answer = _error(path, status, kind, message)
        await self._respond(writer, answer.status, answer.body, answer.content_type)

    @staticmethod
    async def _respond(
        writer: asyncio.StreamWriter,
        status: HTTPStatus,
        body: bytes,
        content_type: str,
        *,
        head_only: bool = False,
        extra_headers: Mapping[str, str] | None = None,
    ) -> None:
        headers = {
            "Content-Type": content_type,
            "Content-Length": str(len(body)),
            "Cache-Control": "no-store",
            "Connection": "close",
            **(extra_headers or {}),
        }
        head = f"HTTP/1.1 {status.value} {status.phrase}\r\n" + "".join(
            f"{name}: {value}\r\n" for name, value in headers.items()
        )
        writer.write(head.encode("latin-1") + b"\r\n" + (b"" if head_only else body))
        await writer.drain()


def _stream_head(content_type: str, headers: Mapping[str, str]) -> bytes:
    """The head of an answer without a length (the connection is closed after it)."""
    return (
        "HTTP/1.1 200 OK\r\n"
        f"Content-Type: {content_type}\r\n"
        "Cache-Control: no-store\r\nConnection: close\r\n"
        + "".join(f"{k}: {v}\r\n" for k, v in headers.items())
        + "\r\n"
    ).encode("latin-1")


def _headers(lines: list[str]) -> tuple[dict[str, str], str | None]:
    """The header fields by lower-case name, and the name of a field that may be given once
    but came twice (``SINGLE_HEADERS``), else None."""
    headers: dict[str, str] = {}
    for line in lines:
        name, sep, value = line.partition(":")
        if sep:
            name = name.strip().lower()
            if name in SINGLE_HEADERS and name in headers:
                return headers, name
            headers[name] = value.strip()
    return headers, None


def _peer(writer: asyncio.StreamWriter, which: str = "peername") -> str:
    peer = writer.get_extra_info(which)
    return str(peer[0]) if isinstance(peer, tuple) and peer else ""


def _json(doc: Mapping[str, Any]) -> bytes:
    return (json.dumps(doc, default=str, indent=1, sort_keys=False) + "\n").encode()
