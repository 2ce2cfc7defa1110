"""The Modbus server's listening sockets and its own accept loop (event loop only).

asyncio's ``create_server`` accepts every connection it can and hands it a protocol; at the
file-descriptor limit (EMFILE) it logs a traceback for every failed ``accept`` of a burst and
schedules a retry for each of them, which floods the log and the loop (measured: 51,072
tracebacks in seconds under ``prlimit --nofile=1024``). Here each readable listening socket
gets at most ``ACCEPT_BATCH`` accepts per turn of the loop, and each accepted socket goes to
``on_socket(sock, address)`` before any protocol exists, so a connection past a cap is closed
at once (``modbus.admission``). When ``accept`` fails for lack of resources (EMFILE, ENFILE,
ENOBUFS, ENOMEM) the listener stops accepting for ``ACCEPT_PAUSE_S`` and resumes, with one log
line per period (rate-limited, no traceback): the kernel keeps the waiting connections in the
listen queue meanwhile.

Imports: the standard library, runtime.ratelimit.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
from collections.abc import Callable

from canopen_gateway.runtime.ratelimit import RateLimitedLog

log = logging.getLogger("gateway.modbus")

#: the listen queue: a burst of connections waits here while the loop accepts and refuses
#: them (a PLC connecting during a flood must not find it full)
LISTEN_BACKLOG = 128
#: accepts per readable event of one listening socket (the rest wait for the next turn)
ACCEPT_BATCH = 64
#: accept pauses this long when the process is out of file descriptors or buffers
ACCEPT_PAUSE_S = 0.5
_OUT_OF_RESOURCES = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)

OnSocket = Callable[[socket.socket, str], None]


async def bind(host: str, port: int) -> list[socket.socket]:
    """Listening sockets for ``host:port`` as asyncio's ``create_server`` binds them (every
    address the name resolves to, ``SO_REUSEADDR``, IPv6 sockets IPv6 only), non-blocking.
    OSError (a port in use) closes what was opened and propagates."""
    loop = asyncio.get_running_loop()
    infos = await loop.getaddrinfo(
        host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
    )
    socks: list[socket.socket] = []
    seen: set[tuple[int, object]] = set()
    bound = port
    try:
        for family, kind, proto, _, address in infos:
            if (family, address) in seen:
                continue
            seen.add((family, address))
            s = socket.socket(family, kind, proto)
            socks.append(s)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                s.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            s.bind((address[0], bound, *address[2:]))
            bound = s.getsockname()[1]  # port 0: every address on the port the first one got
            s.listen(LISTEN_BACKLOG)
            s.setblocking(False)
    except BaseException:
        for s in socks:
            s.close()
        raise
    return socks


class AcceptLoop:
    """Accepts on listening sockets and hands each new socket to ``on_socket``."""

    def __init__(self, socks: list[socket.socket], on_socket: OnSocket, name: str) -> None:
        self.socks = socks
        self.on_socket = on_socket
        self.name = name
        self.loop: asyncio.AbstractEventLoop | None = None
        self.pauses = 0  # times accept paused for lack of file descriptors
        self._resume: asyncio.TimerHandle | None = None
        self._warn = RateLimitedLog(log)

    @property
    def port(self) -> int:
        return int(self.socks[0].getsockname()[1]) if self.socks else 0

    def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        for s in self.socks:
            self.loop.add_reader(s.fileno(), self._ready, s)

    def _ready(self, sock: socket.socket) -> None:
        for _ in range(ACCEPT_BATCH):
            try:
                conn, address = sock.accept()
            except (BlockingIOError, InterruptedError, ConnectionAbortedError):
                return
            except OSError as exc:
                if exc.errno in _OUT_OF_RESOURCES:
                    self._pause(exc)
                else:
                    self._warn.warning(("accept", exc.errno), "%s: accept failed: %s", self.name, exc)
                return
            conn.setblocking(False)
            peer = address[0] if isinstance(address, tuple) else str(address)
            self.on_socket(conn, str(peer))

    def _pause(self, exc: OSError) -> None:
        """Out of file descriptors: stop accepting for a while; the kernel queues meanwhile."""
        assert self.loop is not None
        self.pauses += 1
        for s in self.socks:
            self.loop.remove_reader(s.fileno())
        self._resume = self.loop.call_later(ACCEPT_PAUSE_S, self._restart)
        self._warn.warning(
            "emfile",
            "%s: cannot accept connections (%s): accepting paused for %.1f s; raise the file "
            "limit (LimitNOFILE, ulimit -n) or lower modbus.max_connections",
            self.name, exc.strerror or exc, ACCEPT_PAUSE_S,
        )  # fmt: skip

    def _restart(self) -> None:
        self._resume = None
        if self.loop is not None and self.socks:
            for s in self.socks:
                self.loop.add_reader(s.fileno(), self._ready, s)

    def close(self) -> None:
        if self._resume is not None:
            self._resume.cancel()
            self._resume = None
        for s in self.socks:
            if self.loop is not None and s.fileno() >= 0:
                self.loop.remove_reader(s.fileno())
            s.close()
        self.socks = []
