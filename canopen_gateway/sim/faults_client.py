"""``canopen-gateway fault``: fault injection into a running gateway's simulated nodes from the
command line, through the gateway's web API (``POST /api/sim/<node>/<action>`` on the health
port; ``canopen_gateway.web.console``). The simulated nodes live inside the running gateway's process,
so the request must reach that process; this command opens no CAN bus of its own.

With ``health.tls`` it speaks HTTPS and trusts the configured certificate itself (``health.tls.cert``,
the one the gateway presents), whatever names it carries: the command reaches its own gateway.

Exit codes: 0 done, 1 the gateway refused or could not be reached (the reason is printed),
2 usage (as for every command).

Imports: the standard library, config (types), sim.faults (the action names).
"""

from __future__ import annotations

import json
import ssl
import sys
import urllib.error
import urllib.request
from typing import Any

from canopen_gateway.config import Config
from canopen_gateway.sim.faults import ACTIONS

TIMEOUT_S = 5.0


def base_url(cfg: Config, url: str | None) -> str:
    if url:
        return url.rstrip("/")
    host = cfg.health.host
    if host in ("0.0.0.0", "::", ""):
        host = "127.0.0.1"
    if ":" in host:
        host = f"[{host}]"
    return f"{'https' if cfg.health.tls else 'http'}://{host}:{cfg.health.port}"


def _client_tls(cfg: Config) -> ssl.SSLContext | None:
    """The configured certificate as the one trusted (its names are not checked: the address is
    the config's own gateway, not a name it was issued to)."""
    if cfg.health.tls is None:
        return None
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.load_verify_locations(cafile=cfg.path_of(cfg.health.tls.cert))
    ctx.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN  # the server's own certificate as anchor
    return ctx


def _call(url: str, token: str | None, post: bool, tls: ssl.SSLContext | None = None) -> tuple[int, dict[str, Any]]:
    req = urllib.request.Request(url, data=b"{}" if post else None, method="POST" if post else "GET")
    req.add_header("Content-Type", "application/json")
    req.add_header("X-Canopen-Client", "cli")  # the event log names the command line
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=TIMEOUT_S, context=tls) as r:
            return r.status, json.loads(r.read() or b"{}")
    except urllib.error.HTTPError as e:
        body = e.read()
        try:
            doc = json.loads(body)
        except ValueError:
            doc = {"message": body.decode("utf-8", "replace").strip() or e.reason}
        return e.code, doc


def run_fault(cfg: Config, node: str | None, action: str | None, url: str | None) -> int:
    if cfg.health.port == 0 and not url:
        print(
            f"error: {cfg.source}: health.port is 0, so the running gateway serves no web API; "
            "set health.port or pass --url",
            file=sys.stderr,
        )
        return 1
    base = base_url(cfg, url)
    try:
        tls = _client_tls(cfg) if base.startswith("https:") else None
        if node is None:
            code, doc = _call(base + "/api/sim", None, post=False, tls=tls)
            if code == 404:
                print(f"error: {base} has no fault injection (an older gateway?)", file=sys.stderr)
                return 1
            print(doc.get("rule_text", ""))
            mine = {n.name for n in cfg.nodes}  # the network's (--network), or every node
            for name, state in (doc.get("nodes") or {}).items():
                if name not in mine:
                    continue
                words = [
                    "unplugged" if state["unplugged"] else "plugged",
                    "heartbeat on" if state["heartbeat"] else "heartbeat off",
                    f"EMCY {state['emcy']}" if state["emcy"] else "no EMCY raised",
                ]
                print(f"{name}: {', '.join(words)}")
            print("actions: " + ", ".join(ACTIONS))
            return 0
        if action not in ACTIONS:
            print(f"error: no fault {action!r}; one of {', '.join(ACTIONS)}", file=sys.stderr)
            return 2
        code, doc = _call(f"{base}/api/sim/{node}/{action}", cfg.web_token(), post=True, tls=tls)
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        print(
            f"error: no gateway answers at {base} ({reason}); start it with this config "
            f"(canopen-gateway run -c {cfg.source}) or pass --url",
            file=sys.stderr,
        )
        return 1
    if code != 200:
        message = doc.get("message") or f"HTTP {code}"
        if code == 404 and "not simulated" not in message and "no fault" not in message:
            message = "the gateway at " + base + " simulates no node (fault injection is off)"
        print(f"error: {message}", file=sys.stderr)
        return 1
    print(f"{node}: {action} done: {ACTIONS[action]}")
    return 0
