"""Start-up failures in one line: the setting, its value, and what went wrong.

The gateway opens its listeners (Modbus TCP, Zenoh, health/web) and its files at start. When one
of them fails, the user needs the key of the configuration to change, not a traceback:
``modbus.port: 5020 on 127.0.0.1 is already in use (another gateway or program listens there)``.
``startup_step(key, value)`` wraps one step of the start and turns the exceptions of sockets,
files and Zenoh into a ``StartupError`` that carries the key, the value and the reason; the
command line prints it as one line and exits 2 after the gateway has released what it opened.

Before anything opens, ``ports_in_use(listeners_of(cfg, ...))`` tries every TCP/UDP port the gateway will
listen on (Modbus, Zenoh listen endpoints, ASCII, health/web): all the ports that cannot be
taken are reported together, one line each (``StartupError.also``), so one failed start says
every port to change. A value an environment variable set is blamed on the variable
(``StartupError.where``, filled in by the gateway, which knows the config).

Imports: the standard library only (Zenoh's errors are recognised by their text, so this module
does not import zenoh); config for its types and its variables' prefix (config.env).
"""

from __future__ import annotations

import errno
import re
import socket
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from canopen_gateway.config.env import ENV_PREFIX

if TYPE_CHECKING:
    from canopen_gateway.config import Config

#: What an errno of bind/connect/open means for a user, in words.
_ERRNO_TEXT = {
    errno.EADDRINUSE: "is already in use (another gateway or program listens there)",
    errno.EADDRNOTAVAIL: "is not an address of this machine",
    errno.EACCES: "is not allowed (ports below 1024 need privileges)",
    errno.ENOENT: "does not exist",
}

#: Zenoh's error texts (zenoh.ZError) and what they mean.
_ZENOH_TEXT = (
    (re.compile(r"address already in use", re.I), _ERRNO_TEXT[errno.EADDRINUSE]),
    (re.compile(r"cannot assign requested address", re.I), _ERRNO_TEXT[errno.EADDRNOTAVAIL]),
    (re.compile(r"permission denied", re.I), _ERRNO_TEXT[errno.EACCES]),
)


class StartupError(Exception):
    """A part of the gateway could not start: ``key`` of the config, its ``value``, ``reason``.

    ``where``: the environment variable that set the key (None: the config file did);
    ``also``: the other parts that could not start either (every busy port at once)."""

    def __init__(
        self,
        key: str,
        value: Any,
        reason: str,
        *,
        where: str | None = None,
        also: Sequence[StartupError] = (),
    ):
        self.key, self.value, self.reason = key, value, reason
        self.where = where
        self.also = list(also)
        super().__init__(f"{key}: {value} {reason}")

    def line(self, source: str) -> str:
        """The line the command line prints for this part, naming the config file (or the
        environment variable that set the key); a port in use says how to choose another."""
        return f"error: {self.where or source}: {self}{self._port_hint(source)}"

    def _port_hint(self, source: str) -> str:
        if self.reason != _ERRNO_TEXT[errno.EADDRINUSE]:
            return ""
        var = ENV_PREFIX + "__".join(part.upper() for part in self.key.split("."))
        if self.where:  # the variable set it: change it there
            return f"; choose another port in {var}"
        value = "'[\"tcp/127.0.0.1:<port>\"]'" if self.key == "zenoh.listen" else "<port>"
        return f"; choose another port: {self.key} in {source}, or {var}={value} for one run"

    def lines(self, source: str) -> list[str]:
        """One line for each part that could not start."""
        return [e.line(source) for e in (self, *self.also)]

    def blamed(self, blame: Callable[[str], str | None]) -> StartupError:
        """Each part's ``where`` from ``blame(key) -> the variable or None``; returns self."""
        for e in (self, *self.also):
            e.where = blame(e.key)
        return self


@dataclass(frozen=True)
class Listener:
    """A port the gateway will listen on: the config ``key``, how the value is ``shown``."""

    key: str
    host: str
    port: int
    shown: str
    udp: bool = False


#: Zenoh endpoint protocols and whether they listen on UDP (the others on TCP).
_ZENOH_UDP = {"tcp": False, "tls": False, "ws": False, "udp": True, "quic": True}
_ENDPOINT_RE = re.compile(r"^(\w+)/\[?([^\]]*?)\]?:(\d+)(?:[?#].*)?$")


def zenoh_listeners(key: str, endpoints: Iterable[str]) -> list[Listener]:
    """The IP ports of Zenoh listen endpoints (``tcp/127.0.0.1:7447``); other locators (unix
    sockets, serial) and port 0 (any free port) are not tried."""
    out = []
    for endpoint in endpoints:
        m = _ENDPOINT_RE.match(endpoint.strip())
        if m is None or m.group(1) not in _ZENOH_UDP or int(m.group(3)) == 0:
            continue
        out.append(Listener(key, m.group(2), int(m.group(3)), endpoint, _ZENOH_UDP[m.group(1)]))
    return out


def listeners_of(cfg: Config, *, modbus: bool, zenoh: bool) -> list[Listener]:
    """Every port a gateway of ``cfg`` will listen on (``modbus``, ``zenoh``: whether it serves
    them), with the key that sets it."""
    out = []
    mb = cfg.modbus
    if modbus and mb.plain:
        out.append(Listener("modbus.port", mb.host, mb.port, f"{mb.port} on {mb.host}"))
    if modbus and mb.tls is not None:
        host = mb.tls.host or mb.host
        out.append(Listener("modbus.tls.port", host, mb.tls.port, f"{mb.tls.port} on {host}"))
    if zenoh and cfg.zenoh.mode != "client":
        out += zenoh_listeners("zenoh.listen", cfg.zenoh.listen)
    a = cfg.ascii
    if a is not None and a.enabled:
        out.append(Listener("ascii.port", a.host, a.port, f"{a.port} on {a.host}"))
    h = cfg.health
    if h.port:
        out.append(Listener("health.port", h.host, h.port, f"{h.port} on {h.host}"))
    return out


def _try_bind(listener: Listener) -> None:
    kind = socket.SOCK_DGRAM if listener.udp else socket.SOCK_STREAM
    infos = socket.getaddrinfo(listener.host or None, listener.port, type=kind)
    family, _, _, _, address = infos[0]
    with socket.socket(family, kind) as s:
        # as the servers bind: a port whose last connection is in TIME_WAIT is free
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(address)


def ports_in_use(listeners: Iterable[Listener]) -> StartupError | None:
    """Every listener whose port cannot be taken now, as one ``StartupError`` (the first, the
    others in ``also``), or None when all are free. Nothing is left open."""
    problems = []
    for listener in listeners:
        try:
            _try_bind(listener)
        except socket.gaierror as exc:
            problems.append(StartupError(listener.key, listener.shown, f"failed: {exc.strerror}"))
        except OSError as exc:
            problems.append(StartupError(listener.key, listener.shown, os_reason(exc)))
    if not problems:
        return None
    first = problems[0]
    return StartupError(first.key, first.value, first.reason, also=problems[1:])


def zenoh_reason(message: str) -> str:
    """The first clause of a Zenoh error, without the Rust source locations it appends."""
    for pattern, text in _ZENOH_TEXT:
        if pattern.search(message):
            return text
    first = message.splitlines()[0] if message else "failed"
    first = re.sub(r"\s+at /\S+", "", first)
    return f"failed: {first.strip()}"


def os_reason(exc: OSError) -> str:
    text = _ERRNO_TEXT.get(exc.errno or 0)
    if text is not None:
        return text
    return f"failed: {exc.strerror or exc}"


@contextmanager
def startup_step(key: str, value: Any, files: dict[str, str] | None = None) -> Iterator[None]:
    """Run one step of the start; any failure leaves as ``StartupError`` naming ``key``.

    ``files`` maps the keys of file settings of this step to their paths, so that a missing
    file is blamed on its own key (``zenoh.auth.password_file``)."""
    try:
        yield
    except StartupError:
        raise
    except FileNotFoundError as exc:
        for file_key, path in (files or {}).items():
            if exc.filename is not None and str(exc.filename).endswith(str(path)):
                raise StartupError(file_key, exc.filename, "does not exist") from None
        raise StartupError(key, exc.filename or value, "does not exist") from None
    except OSError as exc:
        raise StartupError(key, value, os_reason(exc)) from None
    except Exception as exc:
        if type(exc).__name__ == "ZError":  # zenoh.ZError, recognised without importing zenoh
            bound = re.search(r"bound to (\S+?):\s*\[", str(exc))
            where = bound.group(1) if bound else value
            raise StartupError(key, where, zenoh_reason(str(exc))) from None
        if type(exc).__name__ == "CanInterfaceNotImplementedError":  # python-can: cannot load
            reason = str(exc).splitlines()[0] if str(exc) else "is not available"
            raise StartupError(key, value, f"cannot be loaded: {reason}") from None
        raise
