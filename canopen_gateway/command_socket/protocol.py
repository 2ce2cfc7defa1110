"""The command socket's language and where the socket lives, pure: both the gateway
(``command_socket.server``) and the command line (``canopen_gateway.tools.beside``) read them here.

Where: ``command_socket.path`` of the config (relative to the config file), else a socket in
this user's runtime directory named by the gateway and by the config file's absolute path,
so the gateway and a command given the same file find the same socket, and two gateways on
two files never share one: ``$XDG_RUNTIME_DIR/canopen-gateway/<name>-<hash>.sock`` when
``XDG_RUNTIME_DIR`` is set, else ``/tmp/canopen-gateway-<uid>/<name>-<hash>.sock``. The
directory is this user's alone (mode 0700), the socket too (0600): only the gateway's user
(and root) can connect, the one who may already read its config, token included.

Language: one JSON object per line each way (UTF-8, ``\\n``), answered in order:

    {"op": "hello"}                                              -> {"ok": true, "gateway": NAME, "config": PATH, "pid": N, "health_port": P}
    {"op": "sdo_read", "node": N, "object": "0x1008:00", "type": T|null}   -> {"ok": true, "value": V}
    {"op": "sdo_write", "node": N, "object": O, "value": "4", "type": T|null} -> {"ok": true}
    {"op": "nmt", "node": N|"all", "command": "stop"}          -> {"ok": true}

An error is ``{"ok": false, "error": KIND, "message": TEXT}`` with the command service's kind
(``canopen_gateway.errors``) and words. A value that is bytes travels as ``{"hex": "0a 0b"}``.

Imports: hashlib, json, os, socket, struct, pathlib, config (types only).
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canopen_gateway.config import Config

#: the longest line either side sends (an SDO write of a long string fits many times)
MAX_LINE_BYTES = 64 * 1024
#: the operations of the language
OPERATIONS = ("hello", "sdo_read", "sdo_write", "nmt")
#: Linux ``struct ucred`` (pid, uid, gid), what SO_PEERCRED gives
_UCRED = struct.Struct("3i")


def runtime_dirs(environ: Mapping[str, str] | None = None) -> list[Path]:
    """The directories a default socket may be in, the gateway's choice first: the one of
    ``XDG_RUNTIME_DIR`` when set, then ``/run/user/<uid>`` (its usual value, for a command
    run without it), then ``/tmp/canopen-gateway-<uid>``."""
    env = os.environ if environ is None else environ
    uid = os.getuid()
    out = []
    xdg = env.get("XDG_RUNTIME_DIR")
    if xdg:
        out.append(Path(xdg) / "canopen-gateway")
    run = Path(f"/run/user/{uid}/canopen-gateway")
    if run not in out:
        out.append(run)
    out.append(Path(f"/tmp/canopen-gateway-{uid}"))  # noqa: S108 - checked: ours, mode 0700
    return out


def socket_name(cfg: Config) -> str | None:
    """``<gateway name>-<12 hex digits of the config file's absolute path>.sock``; None for a
    config that was not read from a file (nothing else could name it)."""
    if cfg.source == "<memory>":
        return None
    where = str(Path(cfg.source).resolve())
    digest = hashlib.sha256(where.encode()).hexdigest()[:12]
    return f"{cfg.gateway.name[:40]}-{digest}.sock"


def in_process_bus(cfg: Config) -> bool:
    """Whether a bus of this config lives inside the gateway's process (``can.interface:
    virtual``): of any of its networks (a network's view: of that network). The gateway opens
    its socket then, and a command on such a bus looks for it."""
    return any(net.can.interface == "virtual" for net in cfg.network_sections())


def socket_paths(cfg: Config, environ: Mapping[str, str] | None = None) -> list[Path]:
    """Where this config's socket is: the gateway listens on the first, a command tries each.
    Empty when the socket is off (``command_socket.enabled: false``) or cannot be named."""
    section = cfg.command_socket
    if not section.enabled:
        return []
    if section.path:
        return [cfg.base_dir / Path(section.path).expanduser()]
    name = socket_name(cfg)
    if name is None:
        return []
    xdg_set = bool((os.environ if environ is None else environ).get("XDG_RUNTIME_DIR"))
    dirs = runtime_dirs(environ)
    # the gateway's choice: XDG_RUNTIME_DIR when set, else the directory under /tmp
    ordered = dirs if xdg_set else [dirs[-1], *dirs[:-1]]
    return [d / name for d in ordered]


def peer_credentials(sock: socket.socket | None) -> tuple[int, int]:
    """(pid, uid) of the process at the other end of a Unix socket, as the kernel gives them
    (0 and our uid when the platform cannot say: the socket's mode is the guard then). Each
    side checks the other: the gateway its client, the command line the gateway."""
    peercred = getattr(socket, "SO_PEERCRED", None)
    if sock is None or peercred is None:
        return 0, os.getuid()
    pid, uid, _gid = _UCRED.unpack(sock.getsockopt(socket.SOL_SOCKET, peercred, _UCRED.size))
    return pid, uid


def trusted(uid: int) -> bool:
    """Whether a process of ``uid`` may be at the other end: this user, or root."""
    return uid in (os.getuid(), 0)


# --------------------------------------------------------------------------- lines
def line(doc: Mapping[str, Any]) -> bytes:
    """One message as its line."""
    return json.dumps(doc, separators=(",", ":")).encode() + b"\n"


def value_to_json(value: Any) -> Any:
    """An SDO value as JSON carries it (bytes as ``{"hex": ...}``)."""
    if isinstance(value, (bytes, bytearray)):
        return {"hex": bytes(value).hex(" ")}
    return value


def value_from_json(value: Any) -> Any:
    if isinstance(value, dict) and isinstance(value.get("hex"), str):
        return bytes.fromhex(value["hex"])
    return value


def answer_error(kind: str, message: str) -> dict[str, Any]:
    return {"ok": False, "error": kind, "message": message}
