"""The web console's HTTP routes, served by the health server (``gateway.health``) on the same
host and port: pages and static files, a small JSON API, server-sent events, and (with
``web.writes: true``) the commissioning API behind a token.

=====================================  ==========================================================
``GET /``                              overview and nodes table (``static/index.html``)
``GET /node/<name>``                   node page (``static/node.html``)
``GET /commissioning``                 commissioning page; 404 unless ``web.writes: true``
``GET /static/<file>``                 the console's CSS and JavaScript (package data, no CDN)
``GET /api/overview``                  gateway, bus, Modbus, Zenoh figures and the node rows
``GET /api/node/<name>``               a node: row, signals, values, EMCY, register-map rows
``GET /api/stream[?node=<name>]``      server-sent events: ``overview`` + ``nodes``, or
                                       ``node`` + ``values`` of one node (``gateway.web.live``)
``POST /api/commission/<operation>``   ``login``, ``sdo-read``, ``sdo-write``, ``nmt``, ``set``,
                                       ``lss-inquire`` (JSON body); 404 unless writes are on;
                                       401 without ``Authorization: Bearer <token>``, 403 with a
                                       wrong one; 400 with a message for a bad body
=====================================  ==========================================================

Runs on the event loop only (the image's value listener hands off in ``gateway.web.live``).

Imports: health (request/response types), web.live, web.views, web.commissioning, config,
image, commands (types), ratelimit. Never bus/ internals, modbus/ or zenoh_bridge/ modules with I/O.
"""

from __future__ import annotations

import hmac
import json
import logging
from http import HTTPStatus
from importlib import resources
from typing import Any

from gateway import __version__
from gateway.commands import CommandService
from gateway.config import Config
from gateway.health import JSON_TYPE, Request, Response, Stream
from gateway.image import ProcessImage
from gateway.ratelimit import RateLimitedLog
from gateway.web.commissioning import Commissioning, error_doc
from gateway.web.live import LiveHub, Subscriber, TooManyClients
from gateway.web.views import ConsoleModel, OverviewFn

log = logging.getLogger("gateway.web")

CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".png": "image/png",
    ".svg": "image/svg+xml",
}
#: no script, style or connection from anywhere but this server (works without internet)
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


def _json(status: HTTPStatus, doc: Any) -> Response:
    body = (json.dumps(doc, default=str, separators=(",", ":")) + "\n").encode()
    return Response(status, body, JSON_TYPE)


def _load_static() -> dict[str, bytes]:
    files = {}
    for entry in resources.files("gateway.web").joinpath("static").iterdir():
        if entry.is_file() and any(entry.name.endswith(ext) for ext in CONTENT_TYPES):
            files[entry.name] = entry.read_bytes()
    return files


class WebConsole:
    """The console as an ``app`` of ``HealthServer``: ``await console(request)``."""

    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        commands: CommandService,
        overview_fn: OverviewFn | None = None,
        *,
        regmap: Any = None,
    ):
        self.cfg = cfg
        self.writes = cfg.web.writes
        self._token = (cfg.web.token or "").encode()
        self.model = ConsoleModel(cfg, image, commands, overview_fn, regmap=regmap)
        self.hub = LiveHub(image)
        self.commissioning = Commissioning(cfg, commands) if self.writes else None
        self.static = _load_static()
        self.warn = RateLimitedLog(log)

    def start(self, loop: Any) -> None:
        self.hub.attach(loop)

    def stop(self) -> None:
        self.hub.detach()

    # ------------------------------------------------------------------ routing
    async def __call__(self, request: Request) -> Response | Stream | None:
        path = request.path
        if path.startswith("/api/commission/"):
            return await self._commission(request, path.removeprefix("/api/commission/"))
        if request.method not in ("GET", "HEAD"):
            return Response(
                HTTPStatus.METHOD_NOT_ALLOWED, b"GET or HEAD only\n", headers={"Allow": "GET, HEAD"}
            )
        if path in ("/", "/index.html"):
            return self._file("index.html")
        if path.startswith("/node/"):
            name = path.removeprefix("/node/")
            if name not in self.model.meta:
                return self._not_found(f"no node named {name!r}")
            return self._file("node.html")
        if path == "/commissioning":
            return self._file("commission.html") if self.writes else None
        if path.startswith("/static/"):
            return self._file(path.removeprefix("/static/"))
        if path == "/api/overview":
            return _json(HTTPStatus.OK, self._overview_doc())
        if path.startswith("/api/node/"):
            name = path.removeprefix("/api/node/")
            if name not in self.model.meta:
                return self._not_found(f"no node named {name!r}")
            return _json(HTTPStatus.OK, self.model.node_detail(name))
        if path == "/api/stream":
            if request.method == "HEAD":
                return Response(HTTPStatus.OK, b"", "text/event-stream")
            return self._stream(request)
        return None

    def _not_found(self, message: str) -> Response:
        return _json(HTTPStatus.NOT_FOUND, {"error": "not_found", "message": message})

    def _file(self, name: str) -> Response | None:
        body = self.static.get(name)
        if body is None:
            return None
        ext = name[name.rfind(".") :]
        return Response(HTTPStatus.OK, body, CONTENT_TYPES[ext], headers=SECURITY_HEADERS)

    def _overview_doc(self) -> dict[str, Any]:
        return {
            "gateway": self.cfg.gateway.name,
            "version": __version__,
            "writes": self.writes,
            "overview": self.model.overview(),
            "nodes": self.model.node_rows(),
        }

    # ------------------------------------------------------------------ live
    def _stream(self, request: Request) -> Response | Stream:
        node = request.query.get("node")
        if node is not None and node not in self.model.meta:
            return self._not_found(f"no node named {node!r}")
        try:
            sub = self.hub.subscribe(node)
        except TooManyClients as exc:
            return _json(HTTPStatus.SERVICE_UNAVAILABLE, {"error": "busy", "message": str(exc)})

        async def body(reader: Any, writer: Any) -> None:
            await self.hub.pump(sub, self.render, reader, writer)

        return Stream("text/event-stream", body)

    def render(self, sub: Subscriber, full: bool) -> list[tuple[str, Any]]:
        """The events of one update of ``sub`` (clears its dirty sets)."""
        events: list[tuple[str, Any]] = []
        health, sub.dirty_health = sub.dirty_health, set()
        values, sub.dirty_values = sub.dirty_values, set()
        if sub.node is None:
            if full:
                events.append(("overview", self.model.overview()))
            if full or health:
                events.append(("nodes", self.model.node_rows()))
            return events
        if full or health:
            events.append(
                ("node", {"row": self.model.node_row(sub.node), "emcy": self.model.emcy(sub.node)})
            )
        if full or values:
            events.append(("values", self.model.values(sub.node, None if full else values)))
        return events

    # ------------------------------------------------------------------ commissioning
    def _authorised(self, request: Request) -> Response | None:
        """None when the request carries the token; else the 401 / 403 answer."""
        auth = request.headers.get("authorization", "")
        scheme, _, given = auth.partition(" ")
        if scheme.lower() != "bearer" or not given:
            return Response(
                HTTPStatus.UNAUTHORIZED,
                b'{"error":"unauthorized","message":"send Authorization: Bearer <web token>"}\n',
                JSON_TYPE,
                headers={"WWW-Authenticate": 'Bearer realm="canopen-gateway"'},
            )
        if not hmac.compare_digest(given.strip().encode(), self._token):
            self.warn.warning("token", "web console: a commissioning request with a wrong token")
            return _json(HTTPStatus.FORBIDDEN, {"error": "forbidden", "message": "wrong token"})
        return None

    async def _commission(self, request: Request, op: str) -> Response | None:
        if self.commissioning is None:
            return None  # absent: 404, as if it did not exist
        if request.method != "POST":
            return Response(
                HTTPStatus.METHOD_NOT_ALLOWED, b"POST only\n", headers={"Allow": "POST"}
            )
        refused = self._authorised(request)
        if refused is not None:
            return refused
        if op == "login":
            return _json(HTTPStatus.OK, {"ok": True})
        if op not in Commissioning.OPS:
            return self._not_found(
                f"no operation {op!r}; one of login, {', '.join(Commissioning.OPS)}"
            )
        try:
            result = await self.commissioning.run(op, request.body)
        except Exception as exc:  # every failure becomes an answer with words
            status, doc = error_doc(exc)
            if status == HTTPStatus.INTERNAL_SERVER_ERROR:
                log.exception("web commissioning %s failed", op)
            else:
                log.info("web commissioning %s refused: %s", op, doc["message"])
            return _json(status, doc)
        log.info("web commissioning %s: %s", op, result)
        return _json(HTTPStatus.OK, result)
