"""Commissioning commands (``sdo``, ``nmt``) beside a running gateway.

With ``can.interface: virtual`` the bus exists only inside one process: a second process that
opens "the same" bus opens a private, empty copy, and with ``simulate:`` it would even simulate
its own copy of the devices, so an SDO write would "succeed" on devices nobody else sees. So
before such a command opens the bus:

1. If the gateway running this config listens on its command socket (``canopen_gateway.command_socket``:
   a Unix socket only its user can open, found by the config file), the command goes through
   it: local, nothing opened to the cloud (Zenoh writes may stay off).
2. Else, if the config's Zenoh endpoint answers as a gateway (its catalogue under the config's
   prefix), the command goes through that gateway's Zenoh API (``<prefix>/<node>/sdo/..``,
   ``<prefix>/<node>/nmt``), which takes writes only with ``zenoh.writes`` on.
3. Else, if the command would simulate devices (``simulate:``) while the gateway's health port
   is in use (a gateway runs without either way in), it refuses, in one line that says how to
   reach the running gateway instead: its command socket, its console's page for the command,
   and how to turn the commissioning page on (web.writes and a token).
4. Else nothing runs on this config: the command opens the bus itself (and simulates the devices
   of ``simulate:``), and says on stderr that it acts on its own simulated devices.

Other interfaces (socketcan, pcan, remote, ...) are shared by every process: the command opens
the bus beside the gateway, as before.

Imports: zenoh, config, canopen.objref, northbound.keys, command_socket.protocol (where the
socket is, its language). Nothing of bus/ or modbus/.
"""

from __future__ import annotations

import json
import socket
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import zenoh

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.command_socket.protocol import (
    MAX_LINE_BYTES,
    line,
    peer_credentials,
    socket_paths,
    trusted,
    value_from_json,
)
from canopen_gateway.command_socket.protocol import (
    in_process_bus as in_process_bus,  # the tools ask it here too
)
from canopen_gateway.config import Config
from canopen_gateway.northbound.keys import catalog_key, nmt_key, sdo_key

#: how long to wait for a running gateway to answer (loopback: a few ms when one runs)
FIND_TIMEOUT_S = 1.5
QUERY_TIMEOUT_S = 10.0


class RemoteError(Exception):
    """The running gateway answered with an error (its ``message`` in words, its ``kind``)."""

    def __init__(self, kind: str, message: str):
        self.kind = kind
        super().__init__(message)


def _port_in_use(host: str, port: int) -> bool:
    if not port:
        return False
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


class ZenohGateway:
    """A running gateway reached through its Zenoh queryable (a client session on its
    listen endpoint)."""

    def __init__(self, session: zenoh.Session, prefix: str, catalog: dict[str, Any]):
        self.session = session
        self.prefix = prefix
        self.catalog = catalog
        self.endpoint = ""

    def close(self) -> None:
        self.session.close()

    def _get(self, key: str, payload: bytes | None = None) -> Any:
        replies = self.session.get(key, payload=payload, timeout=QUERY_TIMEOUT_S)
        for reply in replies:
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
            assert reply.err is not None  # a reply is ok or err
            body = reply.err.payload.to_bytes()
            try:
                doc = json.loads(body)
            except ValueError:
                raise RemoteError("error", body.decode(errors="replace")) from None
            raise RemoteError(str(doc.get("error", "error")), str(doc.get("message", doc)))
        raise RemoteError("timeout", f"the running gateway did not answer {key}")

    def sdo_read(self, node: str, obj: str, type_: str | None) -> Any:
        key = sdo_key(self.prefix, node, ObjRef.parse(obj))
        return self._get(key + (f"?type={type_}" if type_ else "")).get("value")

    def sdo_write(self, node: str, obj: str, value: str, type_: str | None) -> None:
        body: dict[str, Any] = {"value": _json_scalar(value)}
        if type_:
            body["type"] = type_
        self._get(sdo_key(self.prefix, node, ObjRef.parse(obj)), json.dumps(body).encode())

    def nmt(self, node: str, command: str) -> None:
        self._get(nmt_key(self.prefix, node), json.dumps({"command": command}).encode())


class LocalGateway:
    """A running gateway reached through its command socket (``canopen_gateway.command_socket``)."""

    def __init__(self, sock: socket.socket, path: Path):
        self.sock = sock
        self.reader = sock.makefile("rb")
        self.endpoint = f"its command socket {path}"
        #: what the gateway said of itself (name, config, pid, ``health_port``)
        self.hello: dict[str, Any] = {}

    def close(self) -> None:
        self.reader.close()
        self.sock.close()

    def ask(self, request: dict[str, Any]) -> dict[str, Any]:
        """One request, its answer; an error answer raises ``RemoteError``."""
        try:
            self.sock.sendall(line(request))
            raw = self.reader.readline(MAX_LINE_BYTES)
        except OSError as exc:
            raise RemoteError("error", f"the command socket failed: {exc}") from None
        if not raw:
            raise RemoteError("error", "the gateway closed its command socket")
        doc = json.loads(raw)
        if not doc.get("ok"):
            raise RemoteError(str(doc.get("error", "error")), str(doc.get("message", doc)))
        return dict(doc)

    def sdo_read(self, node: str, obj: str, type_: str | None) -> Any:
        doc = self.ask({"op": "sdo_read", "node": node, "object": obj, "type": type_})
        return value_from_json(doc.get("value"))

    def sdo_write(self, node: str, obj: str, value: str, type_: str | None) -> None:
        self.ask({"op": "sdo_write", "node": node, "object": obj, "value": value, "type": type_})

    def nmt(self, node: str, command: str) -> None:
        self.ask({"op": "nmt", "node": node, "command": command})


def find_local_gateway(cfg: Config, timeout_s: float = QUERY_TIMEOUT_S) -> LocalGateway | None:
    """The gateway running this config, through its command socket; None when none listens
    (or the one that answers runs another gateway's config under this path)."""
    for path in socket_paths(cfg):
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(timeout_s)
        try:
            sock.connect(str(path))
        except OSError:
            sock.close()
            continue
        if not trusted(peer_credentials(sock)[1]):  # a socket another user put there: not ours
            sock.close()
            continue
        gw = LocalGateway(sock, path)
        try:
            gw.hello = gw.ask({"op": "hello"})
        except (RemoteError, ValueError):
            gw.close()
            continue
        if gw.hello.get("gateway") == cfg.gateway.name:
            return gw
        gw.close()
    return None


def _json_scalar(text: str) -> Any:
    """``5`` -> 5, ``0x10`` -> 16, ``1.5`` -> 1.5, anything else as text."""
    try:
        return int(text, 0)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def find_running_gateway(cfg: Config, timeout_s: float = FIND_TIMEOUT_S) -> ZenohGateway | None:
    """The gateway that serves this config's Zenoh endpoint, or None when none answers."""
    z = cfg.zenoh
    endpoints = z.listen if z.mode == "peer" else z.connect
    if not z.enabled or not endpoints:
        return None
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps(endpoints))
    conf.insert_json5("connect/timeout_ms", str(int(timeout_s * 1000)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    try:
        session = zenoh.open(conf)
    except zenoh.ZError:
        return None  # nothing listens there
    prefix = z.key_prefix(cfg.gateway.name)
    try:
        for reply in session.get(catalog_key(prefix), timeout=timeout_s):
            if reply.ok is not None:
                gw = ZenohGateway(session, prefix, json.loads(reply.ok.payload.to_bytes()))
                gw.endpoint = ", ".join(endpoints)
                return gw
    except (zenoh.ZError, ValueError):
        pass
    session.close()
    return None


def refusal(cfg: Config, command: str) -> str | None:
    """The one line that refuses ``command`` on an in-process bus while a gateway holds this
    config's ports without a Zenoh API to go through; None when nothing runs."""
    h = cfg.health
    if not _port_in_use(h.host, h.port):
        return None
    url = f"http://{h.host}:{h.port}"
    if command == "monitor":
        page = f"its web console's bus monitor ({url}/monitor)"
    elif _page_served(f"{url}/commissioning"):
        page = f"its web console's commissioning page ({url}/commissioning)"
    else:  # the page is there only with web.writes and a token (docs/web.md)
        page = (
            f"its web console's commissioning page ({url}/commissioning), which that gateway "
            "serves when started with web.writes and a token: CANOPEN_GATEWAY__WEB__WRITES=true "
            f"CANOPEN_GATEWAY__WEB__TOKEN='a long random text' canopen-gateway run -c {cfg.source}"
        )
    # sdo and nmt go through the gateway's command socket or Zenoh API; scan and monitor never do
    via_zenoh = (
        "; or start it with its command socket (command_socket.enabled, the default; this "
        "command then goes through it, as the same user with the same config file)"
        if command.split()[0] in ("sdo", "nmt")
        else ""
    )
    return (
        f"error: {cfg.source}: {cfg.qualify('can.interface')}: virtual: the bus lives inside the gateway running "
        f"at {url}, so `{command}` would act on a private copy of the devices; use {page}"
        f"{via_zenoh}; or give both a bus they share (can.interface: remote, docs/canopen.md)"
    )


def no_socket_hint(cfg: Config) -> str:
    """What to do when the gateway's Zenoh API refuses a write and no command socket of it
    was found: ``; ...`` to append to the error."""
    paths = socket_paths(cfg)
    where = f"at {paths[0]}" if paths else "(command_socket.enabled is false in this config)"
    return (
        f"; no command socket of this gateway {where}: run this command as the gateway's user "
        "with the config file it runs, on a gateway with its command socket on (the default "
        "with an in-process bus; docs/web.md), or open Zenoh writes (zenoh.writes: on), "
        "which opens them to every Zenoh client"
    )


def _page_served(url: str) -> bool:
    """Whether the running gateway serves ``url`` (the commissioning page: 404 while off)."""
    try:
        with urllib.request.urlopen(url, timeout=FIND_TIMEOUT_S) as r:
            return bool(r.status == 200)
    except (urllib.error.URLError, OSError, ValueError):
        return False


def private_note(cfg: Config) -> str:
    names = ", ".join(n.name for n in cfg.simulated_nodes()) or "none"
    return (
        f"note: {cfg.source}: {cfg.qualify('can.interface')}: virtual and no gateway runs on this config: acting "
        f"on this command's own simulated devices ({names})"
    )
