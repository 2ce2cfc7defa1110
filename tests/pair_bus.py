"""A CAN bus shared by processes that says who sent every frame, and can cut or unplug one member.

``PairBus`` is a small socketcand server on 127.0.0.1 (socketcand's ASCII protocol over TCP, the
one python-can's ``socketcand`` interface speaks: ``< hi >``, ``< open NAME >`` / ``< ok >``,
``< rawmode >`` / ``< ok >``, then ``< send ID LEN B0 B1 .. >`` from a client and
``< frame ID SEC.USEC DATA >`` to it). It relays every frame a client sends to every other
connected client, never back to its sender (no echo: SocketCAN without
``receive_own_messages``). Each client is a *member*, named by the channel it opens: a gateway
process configured with ``can: {interface: socketcand, host: 127.0.0.1, port: bus.port,
channel: NAME}`` (``can_section(NAME)``) is member NAME; a test takes part with
``open_bus(NAME)`` (the gateway's socketcand client, a python-can bus, e.g. under a canopen
``LocalNode``).

What a real bus cannot say, this one records: ``frames`` holds every frame that reached the
relay, in relay order, with its sender and whether it was delivered to anyone.

Faults, one member at a time:

- ``cut(NAME)`` / ``mend(NAME)``: a cable cut. The connection stays open; the member hears
  nothing and nothing it sends reaches anyone (recorded with ``delivered=False``). Its driver
  cannot notice: its sends succeed.
- ``unplug(NAME)`` / ``plug(NAME)``: the adapter lost. Its connection is closed (EOF, as a
  socketcand daemon that restarts) and a reconnect of that name is closed at once, as soon as
  it names its channel (``< open NAME >``), until ``plug(NAME)``.
- ``mute(NAME)`` / ``unmute(NAME)``: its transmitter fails silently: it hears everything,
  nothing it sends reaches anyone (``delivered=False``), its driver cannot notice.
- ``split(GROUP, GROUP, ...)`` / ``heal()``: the bus in parts: a frame reaches only the members
  of its sender's group (a member named in no group hears and reaches no one).

A member may hold several connections (a gateway process whose simulated devices open the same
``can:`` section): they hear each other, as sockets on one SocketCAN interface do (its local
loopback), also while the member is cut, and they are one member for ``cut`` and ``unplug``.
``delivered`` says whether another member heard a frame. Threads: an accept thread; per member a reader (parses, records, relays: the relay
order is the record order) and a writer (its own queue, so a member that stops reading, e.g. a
frozen process, holds up no one). It never pauses.

Imports: python-can, canopen_gateway.bus.socketcand_bus (the client of every member) and the standard library.
"""

from __future__ import annotations

import contextlib
import queue
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from canopen_gateway.bus.socketcand_bus import SocketcandBus


@dataclass(frozen=True)
class Frame:
    """One frame as it reached the relay: ``t`` is ``time.monotonic()`` there (the clock of
    every process on this machine); ``delivered`` says whether another member heard it (False
    when its sender was cut, or no other member was connected and uncut). ``dlc`` is the length
    the sender gave (python-can's socketcand client sends a remote frame as its length and no
    data bytes)."""

    t: float
    sender: str
    cob_id: int
    data: bytes
    delivered: bool
    dlc: int = -1
    #: the members it reached
    to: frozenset[str] = frozenset()


class _Member:
    """One client connection: its socket and the queue its writer thread sends from."""

    def __init__(self, name: str, conn: socket.socket):
        self.name = name
        self.conn = conn
        self.out: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self.closed = False

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.out.put(None)
        with contextlib.suppress(OSError):
            self.conn.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.conn.close()


def expect_line(conn: socket.socket, buf: bytes, word: bytes) -> tuple[list[bytes], bytes]:
    """A socketcand server's read of the client's next handshake line ``< WORD ... >``, ``buf``
    the bytes already read: (the line's words, the bytes read past it). Raises
    ``ConnectionError`` when the client leaves or sends another line."""
    while b">" not in buf:
        chunk = conn.recv(256)
        if not chunk:
            raise ConnectionError("client left during the handshake")
        buf += chunk
    msg, _, rest = buf.partition(b">")
    parts = msg.replace(b"<", b" ").split()
    if not parts or parts[0] != word:
        raise ConnectionError(f"expected {word!r}, got {msg!r}")
    return parts, rest


class PairBus:
    """A socketcand-protocol server on 127.0.0.1 relaying frames between its clients. Each
    client is a *member*, named by the channel it opens (``< open NAME >``): a gateway process
    configured with ``can: {interface: socketcand, host: 127.0.0.1, port: bus.port, channel:
    NAME}`` is member NAME."""

    def __init__(self) -> None:
        self._listener = socket.socket()
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(16)
        self.port: int = int(self._listener.getsockname()[1])
        self.frames: list[Frame] = []
        #: connections accepted (handshake done) per name: a reopen counts one more
        self.joins: dict[str, int] = {}
        #: connections refused (closed at once) per name while unplugged
        self.refused: dict[str, int] = {}
        self._lock = threading.Condition()
        self._conns: list[_Member] = []  # every connection past its handshake
        self._cut: set[str] = set()
        self._muted: set[str] = set()
        self._groups: dict[str, int] | None = None  # a split bus: member -> its part
        self._unplugged: set[str] = set()
        self._closing = False
        self._pending: set[socket.socket] = set()  # connections in their handshake
        self._buses: list[can.BusABC] = []
        self._threads: list[threading.Thread] = []
        self._start(self._accept_loop, "pairbus-accept")

    # ------------------------------------------------------------------ members
    def can_section(self, name: str) -> dict[str, Any]:
        """The ``can:`` config section that makes a gateway member ``name``."""
        return {"interface": "socketcand", "host": "127.0.0.1", "port": self.port, "channel": name}

    def open_bus(self, name: str) -> can.BusABC:
        """A python-can bus in this process as member ``name`` (the socketcand client a gateway
        opens, ``canopen_gateway.bus.socketcand_bus``), shut down by ``close()``. Returns once the relay
        counts it connected."""
        with self._lock:
            joins = self.joins.get(name, 0)
        bus = SocketcandBus(channel=name, host="127.0.0.1", port=self.port)
        self._buses.append(bus)
        self._wait(lambda: self.joins.get(name, 0) > joins, 10.0, f"member {name} connected")
        return bus

    def connected(self, name: str) -> bool:
        with self._lock:
            return any(c.name == name for c in self._conns)

    def cut(self, name: str) -> None:
        """Cable cut: ``name`` hears nothing and what it sends reaches no one."""
        with self._lock:
            self._cut.add(name)

    def mend(self, name: str) -> None:
        with self._lock:
            self._cut.discard(name)

    def mute(self, name: str) -> None:
        """Its transmitter fails silently: what ``name`` sends reaches no one; it hears."""
        with self._lock:
            self._muted.add(name)

    def unmute(self, name: str) -> None:
        with self._lock:
            self._muted.discard(name)

    def split(self, *groups: set[str]) -> None:
        """The bus in parts: a frame reaches only the members of its sender's group."""
        with self._lock:
            self._groups = {name: i for i, g in enumerate(groups) for name in g}

    def heal(self) -> None:
        with self._lock:
            self._groups = None

    def unplug(self, name: str) -> None:
        """Adapter lost: close ``name``'s connection (the client reads EOF) and refuse its
        reconnects until ``plug``."""
        with self._lock:
            self._unplugged.add(name)
            gone = [c for c in self._conns if c.name == name]
            self._conns = [c for c in self._conns if c.name != name]
            self._lock.notify_all()
        for c in gone:
            c.close()

    def plug(self, name: str) -> None:
        with self._lock:
            self._unplugged.discard(name)

    # ------------------------------------------------------------------ what was sent
    def sent_by(self, name: str, cob_id: int | None = None) -> list[Frame]:
        """Frames ``name`` sent (delivered or not), optionally only those on ``cob_id``."""
        with self._lock:
            return [
                f for f in self.frames
                if f.sender == name and (cob_id is None or f.cob_id == cob_id)
            ]

    def wait_for(
        self, pred: Callable[[Frame], bool], timeout_s: float = 10.0, after: int = 0
    ) -> Frame:
        """Block until a frame of index >= ``after`` satisfies ``pred``; return it. Raises
        ``TimeoutError`` after ``timeout_s``. (``after=len(bus.frames)`` looks only ahead.)
        It blocks: from a coroutine on the loop of an in-process gateway, call it through
        ``await asyncio.to_thread(bus.wait_for, pred, ...)`` (else the gateway stops too)."""
        deadline = time.monotonic() + timeout_s
        i = after
        with self._lock:
            while True:
                while i < len(self.frames):
                    if pred(self.frames[i]):
                        return self.frames[i]
                    i += 1
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no frame matched after index {after} in {timeout_s} s")
                self._lock.wait(left)

    def _wait(self, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
        with self._lock:
            if not self._lock.wait_for(cond, timeout_s):
                raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")

    # ------------------------------------------------------------------ the relay
    def _start(self, target: Callable[..., None], name: str, *args: Any) -> None:
        t = threading.Thread(target=target, args=args, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def _accept_loop(self) -> None:
        while True:
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return  # closed
            if self._closing:
                conn.close()
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._start(self._serve, "pairbus-client", conn)

    def _serve(self, conn: socket.socket) -> None:
        """Handshake, then read this member's frames until EOF."""
        with self._lock:
            self._pending.add(conn)
        try:
            name, rest = self._handshake(conn)
        except (OSError, ConnectionError):
            with contextlib.suppress(OSError):
                conn.close()
            return
        finally:
            with self._lock:
                self._pending.discard(conn)
        if name is None:
            return
        member = _Member(name, conn)
        with self._lock:
            self._conns = [*self._conns, member]
            self.joins[name] = self.joins.get(name, 0) + 1
            self._lock.notify_all()
        threading.current_thread().name = f"pairbus-rx-{name}"
        self._start(self._write_loop, f"pairbus-tx-{name}", member)
        self._read_loop(member, rest)
        with self._lock:
            if member in self._conns:
                self._conns = [c for c in self._conns if c is not member]
                self._lock.notify_all()
        member.close()

    def _handshake(self, conn: socket.socket) -> tuple[str | None, bytes]:
        """socketcand's greeting: the member's name and the bytes read past the handshake.
        A name that is unplugged is closed as soon as it is named: (None, b"")."""
        conn.sendall(b"< hi >")
        parts, buf = expect_line(conn, b"", b"open")
        name = parts[1].decode("ascii", "replace") if len(parts) > 1 else ""
        with self._lock:
            refused = name in self._unplugged or self._closing
            if refused:
                self.refused[name] = self.refused.get(name, 0) + 1
        if refused:
            conn.close()
            return None, b""
        conn.sendall(b"< ok >")
        _, buf = expect_line(conn, buf, b"rawmode")
        conn.sendall(b"< ok >")
        return name, buf

    def _write_loop(self, member: _Member) -> None:
        # every member is the gateway's socketcand client, which takes frames that arrive with
        # the handshake's last ``< ok >`` (python-can 4.6.1's own client fails its open then)
        while True:
            data = member.out.get()
            if data is None:
                return
            try:
                member.conn.sendall(data)
            except OSError:
                return

    def _read_loop(self, member: _Member, buf: bytes) -> None:
        while True:
            *msgs, buf = buf.split(b">")
            for m in msgs:
                self._relay(member, m)
            try:
                chunk = member.conn.recv(65536)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk

    def _relay(self, member: _Member, raw: bytes) -> None:
        """One ``< send ID LEN B0 .. >`` from ``member``: record it, queue it to the others."""
        parts = raw.replace(b"<", b" ").split()
        if len(parts) < 3 or parts[0] != b"send":
            return
        try:
            cob_id = int(parts[1], 16)
            dlc = int(parts[2], 16)
            data = bytes(int(b, 16) for b in parts[3:])
        except ValueError:
            return
        with self._lock:
            if member not in self._conns:
                return  # unplugged meanwhile: its frames reach no one
            name = member.name
            out = name in self._cut or name in self._muted
            groups = self._groups
            part = groups.get(name, -1) if groups is not None else 0
            to = [
                c for c in self._conns
                if c is not member and (c.name == name or not (
                    out or c.name in self._cut or (groups is not None and groups.get(c.name, -2) != part)
                ))
            ]  # fmt: skip
            reached = frozenset(c.name for c in to if c.name != name)
            self.frames.append(Frame(time.monotonic(), name, cob_id, data, bool(reached), dlc, reached))
            if to:
                width = 8 if len(parts[1]) > 3 else 3
                line = (
                    f"< frame {cob_id:0{width}X} {time.time():.6f} {data.hex().upper()} >"
                ).encode()
                for c in to:
                    c.out.put(line)
            self._lock.notify_all()

    # ------------------------------------------------------------------ stop
    def close(self) -> None:
        """Close the buses of ``open_bus``, every connection and the listener."""
        for bus in self._buses:
            with contextlib.suppress(Exception):
                bus.shutdown()
        self._buses.clear()
        with self._lock:
            self._closing = True
            members, self._conns = self._conns, []
            pending = list(self._pending)
            self._lock.notify_all()
        for m in members:
            m.close()
        for conn in pending:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self._listener.shutdown(socket.SHUT_RDWR)
        self._listener.close()
        for t in self._threads:
            t.join(timeout=2.0)

    def __enter__(self) -> PairBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
