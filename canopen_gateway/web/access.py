"""Who may use the web console: the one place that decides it.

* **Host** (DNS rebinding): a browser tricked into calling the console under another name
  sends that name in ``Host``. A request whose ``Host`` is not an allowed name is answered
  ``421 Misdirected Request``. ``web.allowed_hosts`` lists the names (``name`` or
  ``name:port``; ``*`` any); by default: the bind address, the address the request arrived at,
  ``localhost``, ``127.0.0.1``, ``::1`` and this machine's names (``gethostname``,
  ``getfqdn``), on any port. ``/healthz``, ``/livez`` and ``/metrics`` are not the console's:
  they answer whatever the ``Host`` (probes name the address they reach).
* **The operators' endpoints** (the journal, the bus monitor's stream, SDO reads, fault
  injection, ``Operators.check``): with a token set (``web.token`` / ``web.token_file``) they
  need it, as ``Authorization: Bearer <token>`` or the console's session cookie
  (``POST /api/login`` sets it: HttpOnly, SameSite=Strict, a value derived from the token,
  never the token); without a token they answer clients on this machine only (loopback), and
  say how to open them to others. The overview pages stay open. The commissioning API takes
  the bearer header only (``cookie_ok=False``).
* **Wrong tokens** (``LoginGuard``): after ``FAILURES_LIMIT`` wrong tokens from one address
  within ``FAILURES_WINDOW_S``, that address is answered ``429`` with ``Retry-After`` for
  ``BLOCK_S``, doubled at each new block up to ``MAX_BLOCK_S`` (its right token included:
  guessing stops). Each wrong token is logged with the address (rate-limited) and audited
  (``commands.audit.RefusalAudit``).
* **Streams per client** (``ClientSlots``): live pages and monitor pages per client address,
  so one client cannot take every stream and lock the others out.

Runs on the event loop only (no lock).

Imports: http.server (request/response types), northbound.networks (loopback addresses),
commands.audit (the refusal audit, who asked), runtime.ratelimit.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import math
import socket
import time
from collections import deque
from collections.abc import Callable, Iterable
from http import HTTPStatus

from canopen_gateway.commands.audit import RefusalAudit, acting_as
from canopen_gateway.http.server import JSON_TYPE, Request, Response
from canopen_gateway.northbound.networks import client_ip
from canopen_gateway.runtime.ratelimit import RateLimitedLog

log = logging.getLogger("gateway.web")

FAILURES_LIMIT = 10
FAILURES_WINDOW_S = 60.0
BLOCK_S = 60.0
MAX_BLOCK_S = 900.0
COOKIE = "canopen_gateway_session"
_WILDCARD_BINDS = ("", "0.0.0.0", "::")


def _answer(status: HTTPStatus, kind: str, message: str, headers: dict[str, str] | None = None) -> Response:
    body = (json.dumps({"error": kind, "message": message}) + "\n").encode()
    return Response(status, body, JSON_TYPE, headers or {})


def host_name(header: str) -> tuple[str, str]:
    """(name, port) of a Host header (``[::1]:8080`` -> ``::1``, ``8080``); lower-case."""
    h = header.strip().lower()
    if h.startswith("["):
        name, _, rest = h[1:].partition("]")
        return name, rest.removeprefix(":")
    name, sep, port = h.rpartition(":")
    if sep and port.isdigit() and ":" not in name:
        return name, port
    return h, ""


class HostCheck:
    """``web.allowed_hosts``, or the default names (see the module docstring)."""

    def __init__(self, allowed: list[str] | None, bind_host: str) -> None:
        self.any = allowed is not None and "*" in allowed
        if allowed is None:
            names = {"localhost", "127.0.0.1", "::1"}
            if bind_host.lower() not in _WILDCARD_BINDS:
                names.add(bind_host.lower())
            for name in (socket.gethostname(), socket.getfqdn()):
                if name:
                    names.add(name.lower())
            allowed = sorted(names)
        self.entries = [host_name(a) for a in allowed if a != "*"]

    def refusal(self, request: Request) -> Response | None:
        header = request.headers.get("host")
        if self.any or header is None:  # no Host: not a browser (HTTP/1.0 tools)
            return None
        name, port = host_name(header)
        if name == request.local.lower():
            return None
        for allowed_name, allowed_port in self.entries:
            if name == allowed_name and (not allowed_port or port == allowed_port):
                return None
        return _answer(
            HTTPStatus.MISDIRECTED_REQUEST,
            "misdirected",
            f"this console does not answer for host {name!r}; allowed: "
            f"{', '.join(n for n, _ in self.entries)} (web.allowed_hosts)",
        )


class LoginGuard:
    """Wrong tokens per client address and the blocks they earn (see the module docstring)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic, max_clients: int = 4096):
        self.clock = clock
        self.max_clients = max_clients
        self._failures: dict[str, deque[float]] = {}
        self._blocks: dict[str, tuple[float, int]] = {}  # client -> (until, blocks so far)

    def wait_s(self, client: str) -> float:
        """Seconds the client is still refused (0: it may try)."""
        until, _ = self._blocks.get(client, (0.0, 0))
        return max(0.0, until - self.clock())

    def failed(self, client: str) -> float:
        """A wrong token from ``client``; the seconds of the block it starts (0: none)."""
        now = self.clock()
        if len(self._failures) >= self.max_clients and client not in self._failures:
            self._failures.clear()  # a flood of addresses: forget, never grow
        times = self._failures.setdefault(client, deque())
        times.append(now)
        while times and now - times[0] > FAILURES_WINDOW_S:
            times.popleft()
        if len(times) < FAILURES_LIMIT:
            return 0.0
        until, blocks = self._blocks.get(client, (0.0, 0))
        if now - until > MAX_BLOCK_S:
            blocks = 0  # quiet long enough since the last block: start again
        block_s = min(BLOCK_S * 2**blocks, MAX_BLOCK_S)
        if len(self._blocks) >= self.max_clients and client not in self._blocks:
            self._blocks = {c: b for c, b in self._blocks.items() if b[0] > now}
        self._blocks[client] = (now + block_s, blocks + 1)
        times.clear()
        return block_s

    def succeeded(self, client: str) -> None:
        self._failures.pop(client, None)


def _is_loopback(client: str) -> bool:
    ip = client_ip(client)
    return ip is not None and ip.is_loopback


class Operators:
    """The token of the operators' endpoints, its session cookie and the throttle."""

    def __init__(self, token: str | None, refusals: RefusalAudit | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self._token = (token or "").encode()
        self.required = bool(token)
        self._session = (
            hmac.new(self._token, b"canopen-gateway console session", hashlib.sha256).hexdigest()
            if token
            else ""
        )
        self.refusals = refusals
        self.guard = LoginGuard(clock)
        self.warn = RateLimitedLog(log)

    def _given(self, request: Request, cookie_ok: bool) -> tuple[str, str] | None:
        """("bearer" | "cookie", what the request carries), None: no credentials."""
        scheme, _, given = request.headers.get("authorization", "").partition(" ")
        if scheme.lower() == "bearer" and given.strip():
            return "bearer", given.strip()
        if cookie_ok:
            for part in request.headers.get("cookie", "").split(";"):
                name, _, value = part.strip().partition("=")
                if name == COOKIE and value:
                    return "cookie", value
        return None

    def verified(self, request: Request, cookie_ok: bool = True) -> bool:
        """The request carries the token (or the session cookie); no side effect."""
        given = self._given(request, cookie_ok)
        if not self.required or given is None:
            return False
        kind, value = given
        expected = self._token if kind == "bearer" else self._session.encode()
        return hmac.compare_digest(value.encode(), expected)

    def who(self, request: Request) -> str:
        """The audit's identity of a request: its address, and ``token`` when it carries it."""
        return f"web {request.client or '?'}" + (" token" if self.verified(request) else "")

    def check(self, request: Request, *, cookie_ok: bool = True) -> Response | None:
        """None when the request may use an operators' endpoint, else the answer."""
        client = request.client or "?"
        wait_s = self.guard.wait_s(client)
        if wait_s > 0:
            return self._throttled(wait_s)
        if not self.required:
            if _is_loopback(client):
                return None
            return _answer(
                HTTPStatus.FORBIDDEN, "forbidden",
                "without web.token this is served to clients on the gateway's own machine only; "
                "set web.token (or web.token_file) to use it from elsewhere",
            )  # fmt: skip
        given = self._given(request, cookie_ok)
        if self.verified(request, cookie_ok):
            self.guard.succeeded(client)
            return None
        if given is None or given[0] == "cookie":
            # no credentials, or the cookie of another token (it changed since the login):
            # log in again; a stale cookie is not a guess (it cannot be guessed faster than
            # the token), so an open page after a token change does not block its address
            how = "Authorization: Bearer <web token>" + (" or log in (POST /api/login)" if cookie_ok else "")
            return _answer(HTTPStatus.UNAUTHORIZED, "unauthorized", f"send {how}",
                           {"WWW-Authenticate": 'Bearer realm="canopen-gateway"'})  # fmt: skip
        return self._wrong(request)

    def _wrong(self, request: Request) -> Response:
        client = request.client or "?"
        block_s = self.guard.failed(client)
        self.warn.warning(("token", client), "web console: a wrong token from %s (%s %s)",
                          client, request.method, request.path)  # fmt: skip
        if self.refusals is not None:
            with acting_as(f"web {client}"):
                self.refusals.refused("login", "", request.path, None, "wrong token")
        if block_s:  # the next requests of this address are answered 429
            log.warning(
                "web console: %d wrong tokens from %s within %.0f s: its requests are refused "
                "for %.0f s", FAILURES_LIMIT, client, FAILURES_WINDOW_S, block_s,
            )  # fmt: skip
        return _answer(HTTPStatus.FORBIDDEN, "forbidden", "wrong token")

    @staticmethod
    def _throttled(wait_s: float) -> Response:
        return _answer(
            HTTPStatus.TOO_MANY_REQUESTS, "rate_limited",
            f"too many wrong tokens from this address: try again in {wait_s:.0f} s",
            {"Retry-After": str(max(1, math.ceil(wait_s)))},
        )  # fmt: skip

    def login(self, request: Request) -> Response:
        """``POST /api/login`` with the bearer token: the session cookie for the pages."""
        if request.method != "POST":
            return Response(HTTPStatus.METHOD_NOT_ALLOWED, b"POST only\n", headers={"Allow": "POST"})
        if not self.required:
            return _answer(HTTPStatus.NOT_FOUND, "not_found", "no web.token is set: nothing to log in to")
        refused = self.check(request, cookie_ok=False)
        if refused is not None:
            return refused
        cookie = f"{COOKIE}={self._session}; Path=/; HttpOnly; SameSite=Strict"
        body = b'{"ok":true}\n'
        return Response(HTTPStatus.OK, body, JSON_TYPE, {"Set-Cookie": cookie})

    def session_doc(self, request: Request) -> dict[str, bool]:
        """``GET /api/session``: whether the operators' endpoints need a token and whether
        this request may use them."""
        allowed = self.verified(request) if self.required else _is_loopback(request.client)
        return {"token_required": self.required, "allowed": allowed}


class ClientSlots:
    """At most ``per_client`` of something (open streams) per client address."""

    def __init__(self, per_client: int) -> None:
        self.per_client = per_client
        self._held: dict[str, int] = {}

    def full(self, client: str) -> bool:
        return self._held.get(client, 0) >= self.per_client

    def take(self, client: str) -> bool:
        n = self._held.get(client, 0)
        if n >= self.per_client:
            return False
        self._held[client] = n + 1
        return True

    def give(self, client: str) -> None:
        n = self._held.get(client, 0) - 1
        if n > 0:
            self._held[client] = n
        else:
            self._held.pop(client, None)

    def held(self) -> Iterable[tuple[str, int]]:
        return self._held.items()
