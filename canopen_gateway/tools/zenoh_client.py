"""``canopen-gateway get`` and ``sub``: the gateway's Zenoh keys read from the command line, as
the cloud sees them, with the connect settings of the gateway's own config (no zenoh-cli, no
Zenoh config of one's own to write).

The session is a Zenoh client of the config's endpoints: the gateway's ``listen`` endpoints
when it is a peer (a wildcard address read as this machine), then its ``connect`` endpoints
(its router); its TLS files and its user and password when it has them. A key is relative to
the config's prefix (``wire/value/position`` is ``canopen/demo/wire/value/position``) unless it
starts with the prefix or with ``/`` (``/canopen/*/catalog``: as written, without the ``/``);
selector parameters (``?_time=[now(-1h)..]``) go with it.

Every reply or sample is one line, ``<key> <payload>`` (text as sent, bytes in hex); an error
reply is ``error: <key>: <payload>`` on stderr. Exit 0 when all went well, 1 otherwise (an
error reply, no reply within the time-out, no endpoint answering), 2 for a config without
Zenoh.

Imports: zenoh, json, config, runtime.startup (a Zenoh error in words), zenoh_bridge.session
(TLS_KEYS: the TLS keys the gateway's session sets). Nothing of bus/.
"""

from __future__ import annotations

import json
import queue
import sys
import time
from typing import Any, TextIO

import zenoh

from canopen_gateway.config import Config
from canopen_gateway.runtime.startup import zenoh_reason
from canopen_gateway.zenoh_bridge.session import TLS_KEYS

#: how long a client waits for a router or the gateway to accept it
CONNECT_TIMEOUT_MS = 3000


def endpoints(cfg: Config) -> list[str]:
    """Where the gateway of ``cfg`` can be reached: its listen endpoints (a peer), a wildcard
    address as this machine's loopback, then its connect endpoints."""
    z = cfg.zenoh
    listen = z.listen if z.mode == "peer" else []
    local = [e.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for e in listen]
    return list(dict.fromkeys([*local, *z.connect]))


def client_config(cfg: Config) -> zenoh.Config:
    """A client session's config for ``cfg``'s endpoints, TLS files and credentials."""
    z = cfg.zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(endpoints(cfg)))
    conf.insert_json5("connect/timeout_ms", str(CONNECT_TIMEOUT_MS))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if z.tls is not None:
        for key in TLS_KEYS:
            value = getattr(z.tls, key)
            if key.startswith("listen_"):
                continue  # a client listens nowhere
            if isinstance(value, str):
                value = str(cfg.base_dir / value)
            if value is not None:
                conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    a = z.auth
    if a is not None and a.user is not None:
        password = a.password
        if a.password_file is not None:
            password = (cfg.base_dir / a.password_file).read_text(encoding="utf-8").strip()
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(a.user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return conf


def key_of(cfg: Config, key: str) -> str:
    """``key`` under the config's prefix (see the module docstring), parameters kept."""
    prefix = cfg.zenoh.key_prefix(cfg.gateway.name)
    path, sep, params = key.partition("?")
    if path.startswith("/"):
        path = path[1:]
    elif not (path == prefix or path.startswith(prefix + "/")):
        path = f"{prefix}/{path.strip('/')}" if path.strip("/") else prefix
    return path + sep + params


def _text(payload: bytes) -> str:
    try:
        return payload.decode("utf-8")
    except UnicodeDecodeError:
        return payload.hex(" ")


def _open(cfg: Config, err: TextIO) -> zenoh.Session | None:
    if not cfg.zenoh.enabled:
        print(f"error: {cfg.source}: zenoh.enabled is false: the gateway serves no Zenoh keys", file=err)
        return None
    try:
        return zenoh.open(client_config(cfg))
    except zenoh.ZError as exc:
        print(
            f"error: no Zenoh router or gateway answers at {', '.join(endpoints(cfg)) or '(no endpoint)'} "
            f"({zenoh_reason(str(exc))}); start the gateway of {cfg.source} (canopen-gateway run -c {cfg.source})",
            file=err,
        )
        return None


def run_get(cfg: Config, key: str, timeout_s: float, out: TextIO | None = None, err: TextIO | None = None) -> int:  # fmt: skip
    """``canopen-gateway get``: every reply of one query, one line each (on stdout; errors on
    stderr)."""
    out, err = out or sys.stdout, err or sys.stderr
    session = _open(cfg, err)
    if session is None:
        return 2 if not cfg.zenoh.enabled else 1
    selector = key_of(cfg, key)
    ok = errors = 0
    try:
        for reply in session.get(selector, timeout=timeout_s):
            if reply.ok is not None:
                ok += 1
                print(f"{reply.ok.key_expr} {_text(reply.ok.payload.to_bytes())}", file=out, flush=True)
            else:
                errors += 1
                assert reply.err is not None  # a reply is ok or err
                print(f"error: {selector}: {_text(reply.err.payload.to_bytes())}", file=err)
        if not ok and not errors and "_time=" in selector.partition("?")[2] and _gateway_alive(cfg, session, timeout_s):
            # history as Zenoh storages answer it: nothing in the range is an empty answer
            print(f"{selector}: no history in that range (the gateway answered nothing)", file=err)
            return 0
    finally:
        session.close()
    if not ok and not errors:
        print(f"error: no reply to {selector} within {timeout_s:g} s (no such key, or the gateway is not there)", file=err)  # fmt: skip
        return 1
    return 1 if errors else 0


def _gateway_alive(cfg: Config, session: Any, timeout_s: float) -> bool:
    """The gateway of ``cfg`` declares its liveliness token (``<prefix>/alive/_gateway``)."""
    token = key_of(cfg, "alive/_gateway")
    return any(r.ok is not None for r in session.liveliness().get(token, timeout=timeout_s))


def run_sub(
    cfg: Config, key: str, count: int | None, duration_s: float | None,
    out: TextIO | None = None, err: TextIO | None = None,
) -> int:  # fmt: skip
    """``canopen-gateway sub``: each sample, one line, until ``count`` samples, ``duration_s``
    or Ctrl-C."""
    out, err = out or sys.stdout, err or sys.stderr
    session = _open(cfg, err)
    if session is None:
        return 2 if not cfg.zenoh.enabled else 1
    samples: queue.Queue[Any] = queue.Queue()  # the callback runs on a zenoh thread: hand over
    sub = session.declare_subscriber(key_of(cfg, key), lambda s: samples.put((str(s.key_expr), s.payload.to_bytes())))  # fmt: skip
    end = None if duration_s is None else time.monotonic() + duration_s
    seen = 0
    try:
        while count is None or seen < count:
            wait = None if end is None else end - time.monotonic()
            if wait is not None and wait <= 0:
                break
            try:
                k, payload = samples.get(timeout=wait)
            except queue.Empty:
                break
            print(f"{k} {_text(payload)}", file=out, flush=True)
            seen += 1
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
        session.close()
    return 0
