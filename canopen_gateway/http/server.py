"""Health and metrics over HTTP: ``GET /healthz``, ``GET /livez``, ``GET /metrics``, and the web
console's requests, on the gateway's event loop; over TLS with ``health.tls``.

Responsible for: the HTTP/1.1 server of probes, Prometheus scrapes and the web console (its
routing, its bounds, its turns on the event loop), and the shape of the health document
(``build_status``; ``pair_status`` for the role and peer of a hot-standby pair). It knows
nothing of CAN, Modbus or Zenoh: the gateway hands it a ``status_fn`` returning a dict and,
optionally, a metrics registry and an ``app``.

- ``/healthz``: ``status_fn()`` as JSON; 200 when its ``"status"`` is ``"ready"``, else 503 (500
  if ``status_fn`` raises). For readiness probes, load balancers and HEALTHCHECK.
- ``/livez``: 200 as long as the event loop answers. For liveness probes: restarting the gateway
  does not fix a missing router or an unplugged bus, so liveness must not depend on them.
- ``/metrics``: ``prometheus_client.generate_latest(registry)`` in the text format.
- anything else goes to the ``app`` (the web console, ``canopen_gateway.web``), else 404; methods other
  than GET/HEAD on the three paths above 405. These three answer whatever the ``Host`` header
  (probes and scrapes name the address they reach); the app checks it.

**What h11 does** (``connection.py``; h11 is a sans-I/O HTTP/1.1 library: bytes in, events out):
the syntax of the request line and the header fields (RFC 9112: field names and values, no
blank before the colon, obsolete line folding), exactly one ``Host`` in an HTTP/1.1 request
(none, or two, is 400), ``Content-Length`` of ASCII digits only (a ``²``, a ``-1`` or two
different lengths is 400), the body's framing (``Content-Length`` or chunked; another transfer
coding is 501), ``Expect: 100-continue``, keep-alive (an HTTP/1.1 connection carries request
after request; HTTP/1.0 or ``Connection: close`` ends it after the answer), and the answers'
framing (``Content-Length``; chunked for an answer without a length to an HTTP/1.1 client,
close-delimited to an HTTP/1.0 one; a HEAD answer's headers without its body).

**What we do** (``connection.py``, here): the socket, the clock and the bounds h11 leaves to
its user: a request head of at most 8 KiB and 100 fields (431), a body of at most 64 KiB
(413), ``read_timeout_s`` for a head once begun and for its body (408), ``keep_alive_s`` for a
kept-alive connection to send its next request (then closed without a word), an answer the
client does not take for 30 s ends the connection; ``Content-Length`` given twice with equal
values, which h11 takes as one, is 400 (RFC 9112 6.3); at most ``max_connections``
connections at once: past it a connection idle between requests is closed to make room, else
the new one is answered 503 with ``Retry-After``; at most ``ACCEPT_BACKLOG`` connections
accepted per loop iteration. The routing, the answers (``messages``: a ``Response``, a
``Chunked`` answer, each chunk drained before the next is asked for, so the journal's export
of any length takes constant memory; a ``Stream`` of server-sent events, whose body writes
until the client goes away, the connection closed after), and the turns: with ``turns``
(``turns.LoopTurns``: the PLC first) each app request waits for its turn on the event loop
before the app renders it; when too many wait, it is answered 503 ``busy`` with
``Retry-After``. The app's own limits (streams per client, the Host check, the token) are the
app's (``canopen_gateway.web.access``).

**TLS** (``tls``, an ``ssl.SSLContext`` from ``http.tls``, config ``health.tls``): the same
server behind a TLS handshake of at most ``read_timeout_s``; a client that speaks plain HTTP to
it fails the handshake and gets no HTTP answer (not even a 400 page); the server goes on.

Why a server on the gateway's own event loop and not ``http.server`` in a thread: ``status_fn``,
the metrics collectors and the console read the process image on the thread that writes it,
without locks; it starts and stops with the gateway and costs no thread. Why h11 and not
aiohttp: h11 parses and frames and nothing else, so the routing, the turns and the bounds stay
ours, on our loop, as they were; aiohttp would bring its own server, router and limits.

Config (section ``health:`` of the gateway config): ``host`` (127.0.0.1), ``port`` (0 = off),
``tls: {cert, key}``. Port 0 passed to ``HealthServer`` itself binds an ephemeral port (see
``.port``): the caller decides that 0 in the config means "do not start one".

Imports: the standard library, prometheus_client, runtime.turns, http.messages (the request
and its answers, re-exported here) and http.connection (one connection, by h11).
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import json
import logging
import ssl
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import KW_ONLY, dataclass, field
from http import HTTPStatus
from typing import Any

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from canopen_gateway.http.connection import (
    KEEP_ALIVE_S,
    MAX_REQUEST_BODY_BYTES,
    MAX_REQUEST_HEAD_BYTES,
    HttpConnection,
)
from canopen_gateway.http.messages import (
    JSON_TYPE,
    TEXT_TYPE,
    Answer,
    App,
    Chunked,
    Request,
    Response,
    Stream,
    StreamOut,
    error_answer,
)
from canopen_gateway.runtime.turns import ACCEPT_BACKLOG, RETRY_AFTER_S, LoopTurns

log = logging.getLogger("gateway.health")  # the name users see in log lines

StatusFn = Callable[[], Mapping[str, Any] | Awaitable[Mapping[str, Any]]]

READY = "ready"
NOT_READY = "not-ready"
HEALTH_PATHS = ("/healthz", "/livez", "/metrics")
#: connections at once (the console's pages keep theirs open between requests)
MAX_CONNECTIONS = 256

__all__ = [
    "JSON_TYPE",
    "MAX_REQUEST_BODY_BYTES",
    "MAX_REQUEST_HEAD_BYTES",
    "NOT_READY",
    "READY",
    "TEXT_TYPE",
    "App",
    "Chunked",
    "HealthServer",
    "Request",
    "Response",
    "Stream",
    "StreamOut",
    "build_status",
    "pair_status",
]


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
    """HTTP endpoint for probes, scrapes and the console on the running event loop.

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
    keep_alive_s: float = KEEP_ALIVE_S
    max_connections: int = MAX_CONNECTIONS
    app: App | None = None
    #: the app's requests take turns on the event loop (the PLC first); None: they do not
    turns: LoopTurns | None = None
    #: HTTPS: the server's TLS context (``http.tls.server_context``); None: plain HTTP
    tls: ssl.SSLContext | None = None
    _server: asyncio.Server | None = field(default=None, init=False)
    _connections: dict[asyncio.Task[None], HttpConnection] = field(default_factory=dict, init=False)
    #: connections answered 503 because ``max_connections`` were open and none was idle
    refused_connections: int = field(default=0, init=False)

    @property
    def port(self) -> int:
        """The port actually bound (the ephemeral one when 0 was asked); 0 before ``start``."""
        if self._server is None or not self._server.sockets:
            return 0
        return self._server.sockets[0].getsockname()[1]

    @property
    def connections(self) -> int:
        """Connections open now."""
        return len(self._connections)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.tls is not None else 'http'}://{host}:{self.port}"

    async def start(self) -> None:
        if self._server is not None:
            raise RuntimeError("health server already started")
        self._server = await asyncio.start_server(
            self._on_connection,
            self.host,
            self.requested_port,
            backlog=ACCEPT_BACKLOG,
            ssl=self.tls,
            ssl_handshake_timeout=self.read_timeout_s if self.tls is not None else None,
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
        conn = HttpConnection(reader, writer, self._dispatch, read_timeout_s=self.read_timeout_s,
                              keep_alive_s=self.keep_alive_s)  # fmt: skip
        full = len(self._connections) >= self.max_connections and not self._make_room()
        self._connections[task] = conn
        try:
            if full:
                self.refused_connections += 1
                await conn.refuse(error_answer("", HTTPStatus.SERVICE_UNAVAILABLE, "busy",
                                               "too many connections; try again shortly",
                                               {"Retry-After": str(RETRY_AFTER_S)}))  # fmt: skip
            else:
                await conn.serve()
        except (ConnectionError, asyncio.IncompleteReadError, ssl.SSLError):
            pass  # the client went away; nothing to answer
        except asyncio.CancelledError:
            # ``stop()`` ends open connections (e.g. event streams): end quietly, asyncio's
            # server would log a cancelled connection task as an error
            if self._server is not None:
                raise
        finally:
            self._connections.pop(task, None)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    def _make_room(self) -> bool:
        """Close one connection that waits idle for its next request; False: none does."""
        for conn in self._connections.values():
            if conn.idle:
                conn.idle = False
                conn.close()
                return True
        return False

    async def _dispatch(self, request: Request) -> Answer:
        """The answer to one request: the probes' paths here, the rest the app's."""
        if self.app is not None and request.path not in HEALTH_PATHS:
            return await self._app_answer(request)
        if request.method not in ("GET", "HEAD"):
            return Response(HTTPStatus.METHOD_NOT_ALLOWED, b"GET or HEAD only\n", TEXT_TYPE, {"Allow": "GET, HEAD"})
        if request.path == "/healthz":
            status, body = await self._health()
            return Response(status, body, JSON_TYPE)
        if request.path == "/livez":
            return Response(HTTPStatus.OK, b'{"status": "alive"}\n', JSON_TYPE)
        if request.path == "/metrics" and self.registry is not None:
            return Response(HTTPStatus.OK, generate_latest(self.registry), CONTENT_TYPE_LATEST)
        return Response(HTTPStatus.NOT_FOUND, b"not found\n", TEXT_TYPE)

    async def _app_answer(self, request: Request) -> Answer:
        assert self.app is not None
        path = request.path
        try:
            if self.turns is None or await self.turns.turn():
                answer = await self.app(request)
            else:
                answer = error_answer(path, HTTPStatus.SERVICE_UNAVAILABLE, "busy",
                                      "too many requests wait; ask again shortly",
                                      {"Retry-After": str(RETRY_AFTER_S)})  # fmt: skip
        except Exception:
            log.exception("web request %s %s failed", request.method, path)
            answer = error_answer(path, HTTPStatus.INTERNAL_SERVER_ERROR, "internal", "internal error (see the log)")
        return answer if answer is not None else error_answer(path, HTTPStatus.NOT_FOUND, "not_found", "not found")

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


def _json(doc: Mapping[str, Any]) -> bytes:
    return (json.dumps(doc, default=str, indent=1, sort_keys=False) + "\n").encode()
