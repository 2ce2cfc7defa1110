"""The gateway's socketcand client (``canopen_gateway/bus/socketcand_bus.py``) against a scripted server
on loopback: one connect per open, frames that come with the handshake's last ``< ok >``, the
frame formats both ways, EOF and a broken pipe raised as ``can.CanOperationError``."""

from __future__ import annotations

import errno
import socket
import threading
from collections.abc import Iterator

import can
import pytest

from canopen_gateway.bus.can_backend import open_can_bus
from canopen_gateway.bus.socketcand_bus import SocketcandBus
from tests.helpers import free_port


class Server:
    """Accepts one client, greets it and answers its handshake; the test drives the rest."""

    def __init__(self, after_rawmode: bytes = b"< ok >") -> None:
        self.listener = socket.socket()
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(1)
        self.port = self.listener.getsockname()[1]
        self.after_rawmode = after_rawmode
        self.conn: socket.socket | None = None
        self.ready = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        conn.sendall(b"< hi >")
        assert conn.recv(256) == b"< open can0 >"
        conn.sendall(b"< ok >")
        assert conn.recv(256) == b"< rawmode >"
        conn.sendall(self.after_rawmode)
        self.conn = conn
        self.ready.set()

    def read(self, n: int) -> bytes:
        assert self.conn is not None
        buf = b""
        while buf.count(b">") < n:
            buf += self.conn.recv(4096)
        return buf

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.listener.close()


@pytest.fixture
def server() -> Iterator[Server]:
    s = Server()
    yield s
    s.close()


def connect(port: int) -> can.BusABC:
    return open_can_bus({"interface": "socketcand", "host": "127.0.0.1", "port": port,
                         "channel": "can0"})  # fmt: skip


def test_nobody_listening_is_refused_at_once_not_retried() -> None:
    with pytest.raises(ConnectionRefusedError):
        connect(free_port())


def test_frames_in_the_same_read_as_the_last_ok_are_received() -> None:
    s = Server(b"< ok >< frame 181 1700000000.000100 0102 >< frame 1ABCDEF0 1700000000.000200 >")
    try:
        bus = connect(s.port)
        try:
            assert isinstance(bus, SocketcandBus)
            first, second = bus.recv(timeout=5), bus.recv(timeout=5)
            assert first is not None and second is not None
            assert (first.arbitration_id, bytes(first.data), first.is_extended_id) == (
                0x181, b"\x01\x02", False
            )
            assert first.timestamp == pytest.approx(1700000000.0001)
            assert (second.arbitration_id, second.dlc, second.is_extended_id) == (0x1ABCDEF0, 0, True)
        finally:
            bus.shutdown()
    finally:
        s.close()


def test_sends_in_socketcands_format_and_error_frames_arrive_flagged(server: Server) -> None:
    bus = connect(server.port)
    try:
        server.ready.wait(5)
        bus.send(can.Message(arbitration_id=0x601, data=b"\x40\x18\x10\x01", is_extended_id=False))
        bus.send(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False))
        assert server.read(2) == b"< send 601 4 40 18 10 01 >< send 701 1  >"
        assert server.conn is not None
        server.conn.sendall(b"< error 20000004 1700000000.5 >")
        msg = bus.recv(timeout=5)
        assert msg is not None and msg.is_error_frame and msg.arbitration_id == 0x4  # error class bits
    finally:
        bus.shutdown()


def test_the_server_closing_the_connection_raises_then_sends_fail_with_their_errno(
    server: Server,
) -> None:
    bus = connect(server.port)
    try:
        server.ready.wait(5)
        assert server.conn is not None
        server.conn.close()
        with pytest.raises(can.CanOperationError, match="closed the connection"):
            bus.recv(timeout=5)
        with pytest.raises(can.CanOperationError) as refused:
            for _ in range(100):  # the first sends may still go into the socket's buffer
                bus.send(can.Message(arbitration_id=0x77F, data=b"\x05", is_extended_id=False))
        assert refused.value.error_code in (errno.EPIPE, errno.ECONNRESET)
    finally:
        bus.shutdown()


def test_a_server_that_closes_during_the_handshake_fails_the_open() -> None:
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)

    def refuse() -> None:
        conn, _ = listener.accept()
        conn.sendall(b"< hi >")
        conn.recv(256)
        conn.close()  # as a socketcand daemon without that channel, or the PairBus unplugged

    threading.Thread(target=refuse, daemon=True).start()
    try:
        with pytest.raises(can.CanInitializationError, match="during the handshake"):
            connect(listener.getsockname()[1])
    finally:
        listener.close()
