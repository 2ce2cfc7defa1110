"""The web console's HTTP routes, served by the health server (``canopen_gateway.http.server``) on the same
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
                                       ``node`` + ``values`` of one node (``canopen_gateway.web.live``)
``POST /api/commission/<operation>``   ``login``, ``sdo-read``, ``sdo-write``, ``nmt``, ``set``,
                                       ``lss-inquire``, ``lss-fast-scan``, ``scan`` (JSON
                                       body); 404 unless writes are on;
                                       401 without ``Authorization: Bearer <token>``, 403 with a
                                       wrong one; 400 with a message for a bad body
``POST /api/login``                    the token as ``Authorization: Bearer``: the session cookie
                                       of the operators' endpoints (``web.access``)
``GET /api/session``                   whether the operators' endpoints need the token and
                                       whether this client may use them
``GET /events``                        event log page (``static/events.html``)
``GET /api/registers.csv``             the register map as ``canopen-gateway registers --csv``
``GET /api/trend/<name>``              the node's trend samples (``canopen_gateway.web.trends``);
                                       ``?after=<seq>``: only newer ones
``GET /api/events``                    recent events (``canopen_gateway.web.events``); filters
                                       ``?node=``, ``?kind=emcy,state,...``, ``?after=<seq>``
``POST /api/read/<name>/<signal>``     SDO upload of one configuration object of the node's
                                       profile (a read, so no ``web.writes`` needed; an
                                       operators' endpoint); needs
                                       ``Content-Type: application/json``; ``READS_PER_S`` per
                                       client (burst ``READ_BURST``), else 429 + ``Retry-After``
``GET /monitor``                       bus monitor page (``static/monitor.html``)
``GET /api/monitor/record``            a trace file of a network's bus (``?network=``, default
                                       the first; ``canopen_gateway.web.recording``)
``GET /api/monitor/stream``            server-sent events of the bus monitor
                                       (``canopen_gateway.web.monitor``): ``hello``, ``frames``,
                                       ``status``; ``?network=line2`` (default the first),
                                       filters ``?node=wire,5``, ``?kind=pdo,emcy``; 400 for an
                                       unknown network, node or kind, 503 past 8 pages of a
                                       network or ``MONITOR_PER_CLIENT`` of one client
``GET /api/journal[.csv|.json]``       the journal's entries of a range (``web.journal_log``);
                                       the exports streamed (chunked); an operators' endpoint
``GET /api/sim``                       simulated nodes, their faults and who may inject them
``POST /api/sim/<name>/<action>``      fault injection into a node simulated in this process
                                       (``canopen_gateway.sim.faults``); see ``web.fault_routes``
=====================================  ==========================================================

Who may use what (``web.access``): every path checks the ``Host`` header first (421 for a
name the console does not answer for: DNS rebinding); the operators' endpoints (the journal,
the bus monitor's stream and recording of every network, SDO reads, fault injection: ``web.fault_routes``) need the token when
one is set and are served to this machine only when none is; wrong tokens are throttled per
client address (429). Live pages and monitor pages are capped per client address
(``LIVE_PER_CLIENT``; ``MONITOR_PER_CLIENT``, every network's pages together) as well as in
total.

The node page's stream also carries ``trend`` events (new samples, once a second) and the
overview stream ``events`` events (new entries of the event log).

Runs on the event loop only (the image's value listener hands off in ``canopen_gateway.web.live``).

Imports: http.server (request/response types), web.access, web.fault_routes, web.live, web.views,
web.commissioning, web.trends, web.events, web.journal_log, web.limits, web.monitor,
web.recording, web.pages, northbound.scaling, northbound.frames (the decoder's type),
runtime.ratelimit, runtime.turns, commands.audit (who asked, for the audit) (the fault injector
is given by the application; the bus driver, for the monitor's tap, too). Never bus/
internals, modbus/ or zenoh_bridge/ modules with I/O.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from http import HTTPStatus
from importlib import resources
from typing import Any

from canopen_gateway import __version__
from canopen_gateway.commands.audit import acting_as
from canopen_gateway.http.server import JSON_TYPE, Chunked, Request, Response, Stream, StreamOut
from canopen_gateway.northbound.frames import FrameDecoder
from canopen_gateway.northbound.scaling import engineering
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.turns import LoopTurns
from canopen_gateway.web.access import ClientSlots, HostCheck, Operators
from canopen_gateway.web.commissioning import Commissioning, error_doc, shown
from canopen_gateway.web.events import KINDS, EventLog, EventLogHandler
from canopen_gateway.web.fault_routes import FaultRoutes
from canopen_gateway.web.journal_log import JournalLog
from canopen_gateway.web.limits import ClientBudget
from canopen_gateway.web.live import LiveHub, Subscriber, TooManyClients
from canopen_gateway.web.monitor import FrameMonitor, FrameSource, NetworkMonitors
from canopen_gateway.web.pages import fill_pages
from canopen_gateway.web.recording import BusRecorder
from canopen_gateway.web.trends import TREND_PERIOD_S, TrendStore
from canopen_gateway.web.views import ConsoleModel

log = logging.getLogger("gateway.web")

#: live pages (``/api/stream``) and monitor pages of one client address at a time
LIVE_PER_CLIENT = 8
MONITOR_PER_CLIENT = 2

CONTENT_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",
    ".png": "image/png",
    ".svg": "image/svg+xml",
}
#: SDO reads of configuration objects from the node page, per client address
READS_PER_S = 2.0
READ_BURST = 5
#: no script, style or connection from anywhere but this server (works without internet)
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}


def _json(status: HTTPStatus, doc: Any) -> Response:
    body = (json.dumps(doc, default=str, separators=(",", ":")) + "\n").encode()
    return Response(status, body, JSON_TYPE)


def _refuse_unless_json_post(request: Request) -> Response | None:
    """None for a POST with a JSON body; else the 405 or 415 answer."""
    if request.method != "POST":
        return Response(HTTPStatus.METHOD_NOT_ALLOWED, b"POST only\n", headers={"Allow": "POST"})
    if not request.headers.get("content-type", "").startswith("application/json"):
        return _json(
            HTTPStatus.UNSUPPORTED_MEDIA_TYPE,
            {"error": "bad_request", "message": "send Content-Type: application/json"},
        )
    return None


def _load_static() -> dict[str, bytes]:
    files = {}
    for entry in resources.files("canopen_gateway.web").joinpath("static").iterdir():
        if entry.is_file() and any(entry.name.endswith(ext) for ext in CONTENT_TYPES):
            files[entry.name] = entry.read_bytes()
    fill_pages(files)
    return files


class WebConsole:
    """The console as an ``app`` of ``HealthServer``: ``await console(request)``."""

    def __init__(
        self,
        model: ConsoleModel,
        *,
        decoder: FrameDecoder | None = None,
        faults: Any = None,
        frames: FrameSource | None = None,
        turns: LoopTurns | None = None,
        journal: Any = None,
        monitors: NetworkMonitors | None = None,
    ):
        #: what the pages and the API show, built from the console's config, image and commands
        self.model = model
        self.cfg = model.cfg
        self.image = model.image
        self.commands = model.commands
        self.writes = self.cfg.web.writes
        #: who may use what: the Host check, the operators' token (``web.token`` or
        #: ``web.token_file``, checked at start), the streams per client
        self.hosts = HostCheck(self.cfg.web.allowed_hosts, self.cfg.health.host)
        self.operators = Operators(self.cfg.web_token(), self.commands.refusals)
        self.live_slots = ClientSlots(LIVE_PER_CLIENT)
        self.monitor_slots = ClientSlots(MONITOR_PER_CLIENT)
        self.hub = LiveHub(self.image)
        self.commissioning = Commissioning(self.cfg, self.commands) if self.writes else None
        self.static = _load_static()
        self.warn = RateLimitedLog(log)
        self.trends = TrendStore(self.image, self.model.meta)
        self.events = EventLog(self.commands.names())
        self._log_handler = EventLogHandler(self.events)
        self.read_budget = ClientBudget(READS_PER_S, READ_BURST)
        self.journal_log = JournalLog(journal, self.commands.names(), headers=SECURITY_HEADERS, turns=turns)
        #: fault injection (``web.fault_routes``): ``faults`` is sim.faults.FaultInjector
        #: when nodes are simulated in this process; "virtual" only when every network's bus is
        #: (a simulated node on any real bus sends real frames)
        virtual = all(n.can.bus_kwargs().get("interface") == "virtual" for n in self.cfg.network_sections())
        self.fault_routes = FaultRoutes(faults, virtual, self.writes, self.operators)
        self._sampler: Any = None
        #: the bus monitor of each network (``frames``: the one bus driver of a single network)
        if monitors is None:
            assert decoder is not None, "a decoder for the bus monitor, or the monitors"
            monitors = NetworkMonitors({"": FrameMonitor(self.cfg, decoder, frames)})
        self.monitors = monitors
        self.monitor = self.monitors.first
        #: the recordings of each network's bus (``GET /api/monitor/record?network=``)
        self.recorder = BusRecorder(self.monitors.sources(), self.cfg.gateway.name, SECURITY_HEADERS)
        self.turns = turns  # live updates take turns on the loop (API requests: in health)

    def start(self, loop: Any) -> None:
        self.hub.attach(loop)
        self.monitors.attach(loop)
        for node in self.image.nodes.values():
            self.events.watch(node)
        self.image.health_listeners.append(self.events.on_health)
        logging.getLogger("gateway").addHandler(self._log_handler)
        self._sampler = loop.create_task(self._sample_trends(), name="web-trends")

    def stop(self) -> None:
        self.hub.detach()
        self.monitors.detach()
        if self.events.on_health in self.image.health_listeners:
            self.image.health_listeners.remove(self.events.on_health)
        logging.getLogger("gateway").removeHandler(self._log_handler)
        if self._sampler is not None:
            self._sampler.cancel()
            self._sampler = None

    async def _sample_trends(self) -> None:
        """The trend store's one writer: a sample every ``TREND_PERIOD_S`` on the loop."""
        loop = asyncio.get_running_loop()
        next_at = loop.time()
        while True:
            try:
                self.trends.sample(time.monotonic(), time.time())
            except Exception as exc:  # keep sampling; say what broke (rate-limited)
                self.warn.warning("trend", "web console: a trend sample failed: %r", exc)
            next_at += TREND_PERIOD_S
            await asyncio.sleep(max(0.0, next_at - loop.time()))

    # ------------------------------------------------------------------ routing
    async def __call__(self, request: Request) -> Response | Stream | Chunked | None:
        path = request.path
        refused = self.hosts.refusal(request)  # DNS rebinding: 421 for another name
        if refused is not None:
            return refused
        if path.startswith("/api/commission/"):
            return await self._commission(request, path.removeprefix("/api/commission/"))
        if path.startswith("/api/read/"):
            return await self._read(request, path.removeprefix("/api/read/"))
        if path.startswith("/api/sim/"):
            return self.fault_routes.apply(request, path.removeprefix("/api/sim/"))
        if path == "/api/login":
            return self.operators.login(request)
        if request.method not in ("GET", "HEAD"):
            return Response(
                HTTPStatus.METHOD_NOT_ALLOWED, b"GET or HEAD only\n", headers={"Allow": "GET, HEAD"}
            )
        if path in ("/", "/index.html"):
            return self._file("index.html")
        if path.startswith("/node/"):
            name = path.removeprefix("/node/")
            if name not in self.model.meta:  # a browser gets a page (404), not JSON
                return self._file("notfound.html", HTTPStatus.NOT_FOUND)
            return self._file("node.html")
        if path == "/commissioning":
            return self._file("commission.html") if self.writes else None
        if path.startswith("/static/"):
            return self._file(path.removeprefix("/static/"))
        if path == "/favicon.ico":  # asked for by browsers and tools whatever the page says
            return self._file("favicon.svg")
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
        if path == "/events":
            return self._file("events.html")
        if path == "/api/registers.csv":
            return self._registers_csv()
        if path.startswith("/api/trend/"):
            return self._trend(request, path.removeprefix("/api/trend/"))
        if path == "/api/events":
            return self._events(request)
        if path == "/api/session":
            return _json(HTTPStatus.OK, self.operators.session_doc(request))
        if path.startswith("/api/journal"):
            return self.operators.check(request) or await self.journal_log.answer(request, path)
        if path == "/api/sim":
            return _json(HTTPStatus.OK, self.fault_routes.doc())
        if path == "/monitor":
            return self._file("monitor.html")
        if path == "/api/monitor/stream":
            # every frame of a network's bus: an operators' endpoint, pages capped per client
            return self.monitors.stream(request, self.turns, self.operators.check, self.monitor_slots)
        if path == "/api/monitor/record":  # every frame of the bus: an operators' endpoint
            return self.operators.check(request) or await self.recorder.answer(request)
        return None

    def _not_found(self, message: str) -> Response:
        return _json(HTTPStatus.NOT_FOUND, {"error": "not_found", "message": message})

    def _file(self, name: str, status: HTTPStatus = HTTPStatus.OK) -> Response | None:
        body = self.static.get(name)
        if body is None:
            return None
        ext = name[name.rfind(".") :]
        return Response(status, body, CONTENT_TYPES[ext], headers=SECURITY_HEADERS)

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
        client = request.client
        if self.live_slots.full(client):
            return _json(HTTPStatus.SERVICE_UNAVAILABLE, {"error": "busy", "message":
                         f"at most {LIVE_PER_CLIENT} live pages per client address"})  # fmt: skip
        try:
            sub = self.hub.subscribe(node)
        except TooManyClients as exc:
            return _json(HTTPStatus.SERVICE_UNAVAILABLE, {"error": "busy", "message": str(exc)})

        async def body(out: StreamOut) -> None:
            if not self.live_slots.take(client):  # another page of it came first
                self.hub.unsubscribe(sub)
                return
            try:
                await self.hub.pump(sub, self.render, out, turns=self.turns)
            finally:
                self.live_slots.give(client)

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
            self._render_more(sub, full, events)
            return events
        if full or health:
            events.append(
                ("node", {"row": self.model.node_row(sub.node), "emcy": self.model.emcy(sub.node)})
            )
        if full or values:
            events.append(("values", self.model.values(sub.node, None if full else values)))
        self._render_more(sub, full, events)
        return events

    # ------------------------------------------------------------------ commissioning
    async def _commission(self, request: Request, op: str) -> Response | None:
        if self.commissioning is None:
            return None  # absent: 404, as if it did not exist
        if request.method != "POST":
            return Response(
                HTTPStatus.METHOD_NOT_ALLOWED, b"POST only\n", headers={"Allow": "POST"}
            )
        refused = self.operators.check(request, cookie_ok=False)  # the bearer header only
        if refused is not None:
            return refused
        if op == "login":
            return _json(HTTPStatus.OK, {"ok": True})
        if op not in Commissioning.OPS:
            return self._not_found(
                f"no operation {op!r}; one of login, {', '.join(Commissioning.OPS)}"
            )
        try:
            with acting_as(self.operators.who(request)):  # the audit: the client, its token
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

    # ------------------------------------------------------------------ first hour
    def _render_more(self, sub: Subscriber, full: bool, events: list[tuple[str, Any]]) -> None:
        """Once a second (``full``): new trend samples for a node page, new log events for the
        overview stream."""
        if not full:
            return
        if sub.node is not None:
            if self.trends.seq > sub.trend_seq and sub.node in self.trends.rings:
                events.append(("trend", self.trends.since(sub.node, sub.trend_seq)))
            sub.trend_seq = self.trends.seq
        else:
            new = self.events.since(sub.event_seq)
            if new:
                events.append(("events", {"events": [e.doc() for e in new]}))
                sub.event_seq = new[-1].seq

    def _registers_csv(self) -> Response:
        body = self.model.regmap.to_csv().encode()
        name = f"{self.cfg.gateway.name}-registers.csv".replace('"', "")
        headers = {**SECURITY_HEADERS, "Content-Disposition": f'attachment; filename="{name}"'}
        return Response(HTTPStatus.OK, body, "text/csv; charset=utf-8", headers=headers)

    @staticmethod
    def _after(request: Request) -> int | Response:
        text = request.query.get("after", "0")
        if not text.isdigit():
            return _json(
                HTTPStatus.BAD_REQUEST,
                {"error": "bad_request", "message": f"after: expected a sequence number, got {text!r}"},
            )
        return int(text)

    def _trend(self, request: Request, name: str) -> Response:
        if name not in self.model.meta:
            return self._not_found(f"no node named {name!r}")
        after = self._after(request)
        if isinstance(after, Response):
            return after
        return _json(HTTPStatus.OK, self.trends.since(name, after))

    def _events(self, request: Request) -> Response:
        after = self._after(request)
        if isinstance(after, Response):
            return after
        node = request.query.get("node") or None
        if node is not None and node not in self.model.meta:
            return self._not_found(f"no node named {node!r}")
        kinds = None
        if request.query.get("kind"):
            kinds = request.query["kind"].split(",")
            wrong = [k for k in kinds if k not in KINDS]
            if wrong:
                return _json(
                    HTTPStatus.BAD_REQUEST,
                    {"error": "bad_request", "message": f"kind: {', '.join(wrong)} is not one of {', '.join(KINDS)}"},
                )
        found = self.events.since(after, node, kinds)
        doc = {"seq": self.events.seq, "kinds": list(KINDS), "events": [e.doc() for e in found]}
        return _json(HTTPStatus.OK, doc)

    async def _read(self, request: Request, rest: str) -> Response:
        """SDO upload of one configuration object (see the module docstring)."""
        refused = _refuse_unless_json_post(request) or self.operators.check(request)
        if refused is not None:
            return refused
        node, _, signal = rest.partition("/")
        metas = self.model.meta.get(node)
        if metas is None:
            return self._not_found(f"no node named {node!r}")
        meta = metas.get(signal)
        if meta is None or meta.source != "SDO" or meta.sig.access == "wo":
            readable = [n for n, m in metas.items() if m.source == "SDO" and m.sig.access != "wo"]
            return self._not_found(
                f"{node} has no configuration object named {signal!r}; "
                f"readable: {', '.join(readable) or 'none'}"
            )
        wait_s = self.read_budget.take(request.client)
        if wait_s > 0:
            retry = max(1, math.ceil(wait_s))
            body = {
                "error": "rate_limited",
                "message": f"at most {READS_PER_S:g} SDO reads a second per client (bursts of "
                f"{READ_BURST}); try again in {wait_s:.1f} s",
                "retry_after_s": round(wait_s, 3),
            }
            resp = _json(HTTPStatus.TOO_MANY_REQUESTS, body)
            return Response(resp.status, resp.body, resp.content_type, {"Retry-After": str(retry)})
        sig = meta.sig
        try:
            raw = await self.commands.sdo_read(node, sig.object, sig.type)
        except Exception as exc:  # every failure becomes an answer with words
            status, doc = error_doc(exc)
            if status == HTTPStatus.INTERNAL_SERVER_ERROR:
                log.exception("web read %s.%s failed", node, signal)
            return _json(status, doc)
        doc = {
            "ok": True,
            "node": node,
            "signal": signal,
            "object": str(sig.object),
            "raw": shown(raw),
            "value": shown(engineering(sig, raw, meta.scaling)),
            "unit": meta.scaling.unit,
            "ts": time.time(),
        }
        text = sig.values.get(raw) if isinstance(raw, int) else None
        if text is not None:
            doc["text"] = text
        return _json(HTTPStatus.OK, doc)

