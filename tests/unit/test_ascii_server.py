"""The ASCII server's connection handling without sockets: a fake transport shows the
back-pressure on reading and writing, the event backlog limit, the write gate's count and an
error of the command service answered without ending the connection."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace
from typing import Any

from canopen_gateway.ascii.server import MAX_PENDING_LINES, AsciiGateway, _Connection
from canopen_gateway.commands.audit import RefusalAudit
from canopen_gateway.config import parse_config
from canopen_gateway.errors import SdoAbort
from canopen_gateway.image import ProcessImage


class FakeTransport(asyncio.Transport):
    def __init__(self) -> None:
        super().__init__()
        self.out = bytearray()
        self.reading = True
        self.closing = False
        self.buffered = 0

    def write(self, data: Any) -> None:
        self.out += data

    def pause_reading(self) -> None:
        self.reading = False

    def resume_reading(self) -> None:
        self.reading = True

    def is_closing(self) -> bool:
        return self.closing

    def close(self) -> None:
        self.closing = True

    def get_write_buffer_size(self) -> int:
        return self.buffered

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return ("127.0.0.1", 40000) if name == "peername" else default

    def lines(self) -> list[str]:
        return self.out.decode("ascii").split("\r\n")[:-1]


class FakeCommands:
    """The command service as the server sees it: node 1 named wire."""

    def __init__(self) -> None:
        self.reads: list[tuple[str, Any, Any]] = []
        self.fail: BaseException | None = None
        self.refusals = RefusalAudit(lambda: None)  # refused writes: not audited here

    def names(self) -> list[str]:
        return ["wire"]

    def node(self, name: str) -> Any:
        return SimpleNamespace(node_id=1)

    async def sdo_read(self, node: str, obj: Any, type_: Any = None) -> Any:
        self.reads.append((node, obj, type_))
        if self.fail is not None:
            raise self.fail
        return b"\x95\x01\x00\x00" if type_ == "bytes" else 405


def connection(writes: bool = False) -> tuple[_Connection, FakeTransport, AsciiGateway, FakeCommands]:
    cfg = parse_config(
        {"nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}], "ascii": {"writes": writes}},
        environ={},
    )
    commands = FakeCommands()
    gw = AsciiGateway(cfg, ProcessImage(), commands)
    conn = _Connection(gw)
    transport = FakeTransport()
    conn.connection_made(transport)
    return conn, transport, gw, commands


async def settle(conn: _Connection) -> None:
    """Let the connection's task run until it waits for something that is not there yet."""
    for _ in range(10000):
        if conn.lines.empty():
            break
        await asyncio.sleep(0)
    for _ in range(10):
        await asyncio.sleep(0)


async def test_a_flood_of_requests_pauses_reading_until_the_queue_is_half_empty() -> None:
    conn, t, _gw, _c = connection()
    conn.data_received(b"[1] info version\r\n" * (MAX_PENDING_LINES + 36))
    assert not t.reading
    await settle(conn)
    assert t.reading
    assert len(t.lines()) == MAX_PENDING_LINES + 36
    conn.connection_lost(None)


async def test_a_client_that_does_not_read_its_answers_gets_no_more_until_the_socket_drains() -> None:
    conn, t, _gw, _c = connection()
    conn.pause_writing()  # the transport's write buffer is over its high-water mark
    conn.data_received(b"[1] info version\r\n[2] info version\r\n")
    await settle(conn)
    assert t.lines() == []
    conn.resume_writing()
    await settle(conn)
    assert [line[:3] for line in t.lines()] == ["[1]", "[2]"]
    conn.connection_lost(None)


async def test_event_lines_are_not_queued_for_a_client_with_64_kib_unsent() -> None:
    conn, t, _gw, _c = connection()
    t.buffered = 64 * 1024 + 1
    conn.send_event("1 1 BOOT_UP")
    assert t.out == b""
    t.buffered = 0
    conn.send_event("1 1 BOOT_UP")
    assert t.lines() == ["1 1 BOOT_UP"]
    conn.connection_lost(None)


async def test_refused_writes_are_counted_and_reads_go_to_the_command_service() -> None:
    conn, t, gw, commands = connection(writes=False)
    conn.data_received(b"[1] 1 w 0x1017 0 u16 1\r\n[2] 1 start\r\n[3] 1 r 0x1018 1 x32\r\n[4] 1 r 0x1018 1\r\n")
    await settle(conn)
    assert t.lines() == ["[1] ERROR:100", "[2] ERROR:100", "[3] 0x00000195", "[4] 405"]
    assert gw.refused == 2
    assert [(n, str(o), ty) for n, o, ty in commands.reads] == [
        ("wire", "0x1018:01", "bytes"), ("wire", "0x1018:01", None)
    ]  # fmt: skip
    conn.connection_lost(None)


async def test_errors_of_the_command_service_are_answered_and_the_connection_goes_on() -> None:
    conn, t, gw, commands = connection()
    commands.fail = SdoAbort(0x08000022)
    conn.data_received(b"[1] 1 r 0x1018 1 u32\r\n")
    await settle(conn)
    commands.fail = RuntimeError("a bug")
    conn.data_received(b"[2] 1 r 0x1018 1 u32\r\n")
    await settle(conn)
    commands.fail = None
    conn.data_received(b"[3] 1 r 0x1018 1 u32\r\n")
    await settle(conn)
    assert t.lines() == ["[1] ERROR:0x08000022", "[2] ERROR:102", "[3] 405"]
    assert (gw.requests, gw.errors) == (3, 2)
    assert not t.closing
    conn.connection_lost(None)


async def test_end_of_input_answers_what_came_then_closes() -> None:
    conn, t, _gw, _c = connection()
    conn.data_received(b"[1] 1 r 0x1018 1 u32\r\n[2] set node 1\r\n")
    assert conn.eof_received() is True  # keep the transport open for the answers
    await settle(conn)
    assert t.lines() == ["[1] 405", "[2] OK"] and t.closing
