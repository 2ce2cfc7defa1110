"""``can.interface: socketcand``: a python-can bus over socketcand's ASCII protocol that says when
its connection is lost.

python-can 4.6.1's own socketcand bus cannot: when the server closes the connection (the
daemon restarts, its host reboots) its receive reads 0 bytes and returns "no frame", forever,
so a reader spins at 100% of a core and never sees an error, and its sends fail with
``BrokenPipeError``; while nobody listens, its open retries ``connect`` without a pause for 10 s
(a warning per attempt). This bus speaks the same protocol (socketcand's rawmode: ``< hi >``,
``< open CHANNEL >`` / ``< ok >``, ``< rawmode >`` / ``< ok >``, then ``< frame ID SEC.USEC
DATA >`` received and ``< send ID LEN B0 B1 .. >`` sent) and takes the same ``can:`` keys
(``host``, ``port``, ``channel``, ``tcp_tune``, ``can_filters``), and:

- raises ``can.CanOperationError`` from ``recv`` when the server closed the connection (EOF) or
  the socket failed, so the driver's "receive failed -> down -> reopen with backoff" runs;
- raises ``can.CanOperationError`` with the socket's errno from ``send`` (EPIPE, ECONNRESET...);
- connects once per open (``ConnectionRefusedError`` at once when nobody listens, a
  ``TimeoutError`` after ``connect_timeout_s`` when nothing answers): the driver's backoff is
  the only retry;
- takes frames that arrive in the same TCP read as the handshake's last ``< ok >`` (python-can's
  client fails its open on them);
- sets TCP_NODELAY (a frame is sent at once, not held by Nagle's algorithm).

``canopen_gateway.bus.can_backend.open_can_bus`` opens it for ``interface: socketcand``.

Imports: python-can and the standard library only.
"""

from __future__ import annotations

import collections
import select
import socket
from typing import Any

import can

#: socketcand's frames are ASCII lines ``< ... >``; more than this without a ``>`` is not one
MAX_LINE = 4096


class SocketcandBus(can.BusABC):
    """A socketcand client (rawmode) whose receive and send raise when the link is lost."""

    def __init__(
        self,
        channel: str,
        host: str,
        port: int,
        tcp_tune: bool = False,
        can_filters: can.typechecking.CanFilters | None = None,
        connect_timeout_s: float = 5.0,
        **kwargs: Any,
    ):
        """
        :param channel: the CAN interface name served by socketcand (``can0``).
        :param host: the socketcand server's address.
        :param port: the socketcand server's port.
        :param tcp_tune: also acknowledge every read at once (TCP_QUICKACK).
        :param can_filters: see :meth:`can.BusABC.set_filters`.
        :param connect_timeout_s: how long the connection and the handshake may take.
        """
        self.channel = channel
        self.channel_info = f"socketcand on {channel}@{host}:{port}"
        self._quickack = bool(tcp_tune) and hasattr(socket, "TCP_QUICKACK")
        self._rx = b""  # bytes received after the last complete line
        self._frames: collections.deque[can.Message] = collections.deque()
        self._sock = socket.create_connection((host, int(port)), timeout=connect_timeout_s)
        try:
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._handshake(channel)
            self._sock.settimeout(None)
        except BaseException:
            self._sock.close()
            raise
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)

    # ------------------------------------------------------------------ handshake
    def _handshake(self, channel: str) -> None:
        self._expect("hi")
        self._sock.sendall(f"< open {channel} >".encode("ascii"))
        self._expect("ok")
        self._sock.sendall(b"< rawmode >")
        self._expect("ok")
        self._parse(b"")  # frames that came with the last "< ok >"

    def _expect(self, word: str) -> None:
        while b">" not in self._rx:
            chunk = self._sock.recv(4096)
            if not chunk:
                raise can.CanInitializationError(
                    f"socketcand server closed the connection during the handshake "
                    f"(waiting for '< {word} >')"
                )
            self._rx += chunk
        line, _, self._rx = self._rx.partition(b">")
        parts = line.replace(b"<", b" ").split()
        if parts != [word.encode("ascii")]:
            text = line.decode("ascii", "replace").strip()
            raise can.CanInitializationError(f"socketcand: expected '< {word} >', got '{text} >'")

    # ------------------------------------------------------------------ receiving
    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._frames:
            return self._frames.popleft(), False
        try:
            ready, _, _ = select.select([self._sock], [], [], timeout)
            if not ready:
                return None, False
            chunk = self._sock.recv(65536)
        except (OSError, ValueError) as exc:  # ValueError: the socket was closed (shutdown)
            raise can.CanOperationError(
                f"socketcand connection failed: {exc}", getattr(exc, "errno", None)
            ) from exc
        if not chunk:
            raise can.CanOperationError("socketcand server closed the connection (EOF)")
        if self._quickack:
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)
        self._parse(chunk)
        # a partial line alone: no frame yet (BusABC.recv calls again with the time left)
        return (self._frames.popleft() if self._frames else None), False

    def _parse(self, chunk: bytes) -> None:
        *lines, rest = (self._rx + chunk).split(b">")
        self._rx = rest if len(rest) <= MAX_LINE else b""
        for line in lines:
            msg = _message(line, self.channel)
            if msg is not None:
                self._frames.append(msg)

    # ------------------------------------------------------------------ sending
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send one frame; raises ``can.CanOperationError`` (with the errno) when the socket
        refuses it. ``timeout`` is ignored (as by python-can's socketcand bus)."""
        if msg.is_extended_id:
            can_id = f"{msg.arbitration_id & 0x1FFFFFFF:08X}"
        else:
            can_id = f"{msg.arbitration_id & 0x7FF:03X}"
        data = " ".join(f"{b:02X}" for b in msg.data[: msg.dlc])
        line = f"< send {can_id} {msg.dlc:X} {data} >".encode("ascii")
        try:
            self._sock.sendall(line)
        except (OSError, ValueError) as exc:
            raise can.CanOperationError(
                f"socketcand send failed: {exc}", getattr(exc, "errno", None)
            ) from exc

    def shutdown(self) -> None:
        super().shutdown()
        try:
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()


def _message(line: bytes, channel: str) -> can.Message | None:
    """``< frame ID SEC.USEC DATA`` (or ``< error ID SEC.USEC``) as a message; None for any
    other line of the protocol."""
    parts = line.split()
    if len(parts) < 4 or parts[0] != b"<" or parts[1] not in (b"frame", b"error"):
        return None
    try:
        can_id = int(parts[2], 16)
        timestamp = float(parts[3])
        data = bytes.fromhex(b"".join(parts[4:]).decode("ascii"))
    except ValueError:
        return None
    if parts[1] == b"error":  # socketcand sends no details: one zero byte, as python-can does
        return can.Message(
            timestamp=timestamp,
            arbitration_id=can_id & 0x1FFFFFFF,
            is_error_frame=True,
            data=b"\0",
            is_extended_id=True,
            is_rx=True,
            channel=channel,
        )
    return can.Message(
        timestamp=timestamp,
        arbitration_id=can_id,
        data=data,
        is_extended_id=len(parts[2]) != 3,
        is_rx=True,
        channel=channel,
    )
