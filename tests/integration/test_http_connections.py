"""The HTTP server's connections over real sockets on 127.0.0.1 (h11 frames them): keep-alive and
pipelining, the end of a connection (HTTP/1.0, ``Connection: close``, a quiet kept-alive one),
chunked request bodies and ``Expect: 100-continue``, and the bounds: a head over 8 KiB, a body
over 64 KiB, ``max_connections`` (an idle connection makes room, else 503)."""

from __future__ import annotations

import asyncio
import http.client
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from http import HTTPStatus

from canopen_gateway.http.connection import MAX_REQUEST_BODY_BYTES
from canopen_gateway.http.server import HealthServer, Request, Response
from tests.helpers import wait_until

TIMEOUT_S = 5.0


async def echo(request: Request) -> Response:
    """An app that says what it got."""
    return Response(HTTPStatus.OK, f"{request.method} {request.path} {len(request.body)}\n".encode())


@asynccontextmanager
async def server(**kw: object) -> AsyncIterator[HealthServer]:
    s = HealthServer("127.0.0.1", 0, lambda: {"status": "ready"}, app=echo, **kw)  # type: ignore[arg-type]
    await s.start()
    try:
        yield s
    finally:
        await s.stop()


async def exchange(port: int, data: bytes) -> bytes:
    """Send ``data``, then read until the server closes the connection."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(data)
    await writer.drain()
    try:
        return await asyncio.wait_for(reader.read(), TIMEOUT_S)
    finally:
        writer.close()


async def test_an_http11_connection_carries_request_after_request() -> None:
    async with server() as s:

        def two_on_one() -> tuple[list[bytes], int, int]:
            conn = http.client.HTTPConnection("127.0.0.1", s.port, timeout=TIMEOUT_S)
            bodies, ports = [], []
            for path in ("/a", "/healthz"):
                conn.request("GET", path)
                bodies.append(conn.getresponse().read())
                assert conn.sock is not None
                ports.append(conn.sock.getsockname()[1])
            conn.close()
            return bodies, ports[0], ports[1]

        bodies, first, second = await asyncio.to_thread(two_on_one)
        assert bodies[0] == b"GET /a 0\n" and b'"ready"' in bodies[1]
        assert first == second  # the same connection


async def test_pipelined_requests_are_answered_in_order() -> None:
    async with server() as s:
        got = await exchange(s.port, b"GET /one HTTP/1.1\r\nHost: x\r\n\r\n"
                                     b"POST /two HTTP/1.1\r\nHost: x\r\nContent-Length: 3\r\n\r\nabc"
                                     b"GET /three HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")  # fmt: skip
        assert got.count(b"HTTP/1.1 200 OK\r\n") == 3
        assert got.index(b"GET /one 0") < got.index(b"POST /two 3") < got.index(b"GET /three 0")
        assert got.endswith(b"GET /three 0\n")  # closed after the one that asked


async def test_http10_gets_its_answer_and_the_connection_ends() -> None:
    async with server() as s:
        got = await exchange(s.port, b"GET /old HTTP/1.0\r\n\r\n")
        assert got.startswith(b"HTTP/1.1 200 OK\r\n") and got.endswith(b"GET /old 0\n")


async def test_a_quiet_kept_alive_connection_is_closed_without_a_word() -> None:
    async with server(keep_alive_s=0.05) as s:
        got = await exchange(s.port, b"GET /x HTTP/1.1\r\nHost: x\r\n\r\n")  # then nothing
        assert got.count(b"HTTP/1.1") == 1 and got.endswith(b"GET /x 0\n")  # no 408 after it


async def test_a_chunked_body_is_read_and_held_to_the_body_bound() -> None:
    async with server() as s:
        got = await exchange(s.port, b"POST /c HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n"
                                     b"Connection: close\r\n\r\n3\r\nabc\r\n2\r\nde\r\n0\r\n\r\n")  # fmt: skip
        assert got.startswith(b"HTTP/1.1 200 OK") and got.endswith(b"POST /c 5\n")
        big = b"%x\r\n%s\r\n" % (MAX_REQUEST_BODY_BYTES + 1, b"x" * (MAX_REQUEST_BODY_BYTES + 1))
        got = await exchange(s.port, b"POST /api/c HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
                                     + big + b"0\r\n\r\n")  # fmt: skip
        assert got.startswith(b"HTTP/1.1 413 ") and b'"too_large"' in got
        got = await exchange(s.port, b"POST /c HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: gzip\r\n\r\n")
        assert got.startswith(b"HTTP/1.1 501 ")


async def test_expect_100_continue_is_answered_before_the_body_is_sent() -> None:
    async with server() as s:
        reader, writer = await asyncio.open_connection("127.0.0.1", s.port)
        writer.write(b"POST /e HTTP/1.1\r\nHost: x\r\nContent-Length: 4\r\nExpect: 100-continue\r\n"
                     b"Connection: close\r\n\r\n")  # fmt: skip
        assert await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), TIMEOUT_S) == b"HTTP/1.1 100 Continue\r\n\r\n"
        writer.write(b"body")
        got = await asyncio.wait_for(reader.read(), TIMEOUT_S)
        writer.close()
        assert got.startswith(b"HTTP/1.1 200 OK") and got.endswith(b"POST /e 4\n")


async def test_a_head_over_8_kib_is_431_even_in_one_piece() -> None:
    async with server() as s:
        got = await exchange(s.port, b"GET /h HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * 9000 + b"\r\n\r\n")
        assert got.startswith(b"HTTP/1.1 431 ")
        many = b"".join(b"X-%d: 1\r\n" % i for i in range(120))
        got = await exchange(s.port, b"GET /h HTTP/1.1\r\nHost: x\r\n" + many + b"\r\n")
        assert got.startswith(b"HTTP/1.1 431 ")


async def test_past_max_connections_an_idle_one_makes_room_else_503() -> None:
    async with server(max_connections=1) as s:
        idle_reader, idle_writer = await asyncio.open_connection("127.0.0.1", s.port)
        idle_writer.write(b"GET /first HTTP/1.1\r\nHost: x\r\n\r\n")
        assert b"GET /first 0\n" in await asyncio.wait_for(idle_reader.readuntil(b"GET /first 0\n"), TIMEOUT_S)
        # the first connection now waits idle for its next request: a new one takes its place
        got = await exchange(s.port, b"GET /second HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        assert got.endswith(b"GET /second 0\n")
        assert await asyncio.wait_for(idle_reader.read(), TIMEOUT_S) == b""  # closed, no answer
        idle_writer.close()
        busy_reader, busy_writer = await asyncio.open_connection("127.0.0.1", s.port)
        busy_writer.write(b"GET /slow HTTP/1.1\r\n")  # a request under way: not idle
        await busy_writer.drain()
        await wait_until(lambda: s.connections == 1, TIMEOUT_S, "the server took the connection")
        got = await exchange(s.port, b"GET /third HTTP/1.1\r\nHost: x\r\n\r\n")
        assert got.startswith(b"HTTP/1.1 503 ") and b"Retry-After: 1\r\n" in got
        assert s.refused_connections == 1
        busy_writer.close()


async def test_an_http11_request_without_a_host_or_with_two_is_400_and_http10_needs_none() -> None:
    async with server() as s:
        for head in (b"GET /api/x HTTP/1.1\r\n\r\n", b"GET /api/x HTTP/1.1\r\nHost: a\r\nHost: b\r\n\r\n"):
            got = await exchange(s.port, head)
            assert got.startswith(b"HTTP/1.1 400 ") and b'"bad_request"' in got and b"Host" in got
        assert (await exchange(s.port, b"GET /x HTTP/1.0\r\n\r\n")).endswith(b"GET /x 0\n")
