"""One client connection of the HTTP server: requests read and answers written through h11
(the HTTP/1.1 protocol, sans-I/O), with the bounds h11 leaves to its user.

h11 turns the bytes received into events (``Request``, ``Data``, ``EndOfMessage``) and the
answer's events into bytes; this module owns the socket, the clock and the bounds: per request
``serve`` reads the head (at most ``MAX_REQUEST_HEAD_BYTES`` and ``MAX_REQUEST_HEADERS``
fields, within ``read_timeout_s``), checks what h11 lets through that we refuse, reads the body
(at most ``MAX_REQUEST_BODY_BYTES``, within ``read_timeout_s``), hands the ``Request`` to the
server's handler and writes its answer (``messages``): a ``Response``, a ``Chunked`` answer
(each chunk drained before the next is asked for) or a ``Stream`` (the connection is closed
after it). A kept-alive connection then waits up to ``keep_alive_s`` for its next request and
is closed quietly if none comes; a write the client does not take within ``WRITE_TIMEOUT_S``
ends the connection. Errors of the client's request are answered with their status (400, 408,
413, 431, 501) and the connection closed, never with an exception.

Runs on the event loop only. Imports: h11, http.messages, the standard library.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import urllib.parse
from collections.abc import Awaitable, Callable
from http import HTTPStatus
from typing import Any

import h11

from canopen_gateway.http.messages import (
    Answer,
    Chunked,
    Request,
    Response,
    StreamOut,
    error_answer,
)

MAX_REQUEST_HEAD_BYTES = 8192
MAX_REQUEST_HEADERS = 100
MAX_REQUEST_BODY_BYTES = 65536
#: a kept-alive connection waits this long for its next request, then is closed quietly
KEEP_ALIVE_S = 15.0
#: an answer the client does not take for this long ends the connection
WRITE_TIMEOUT_S = 30.0
READ_BYTES = 65536
#: a refused client's last bytes are taken (and dropped) this long before the close
LINGER_S = 1.0
_HEAD_END = re.compile(rb"\r?\n\r?\n")

Handler = Callable[[Request], Awaitable[Answer]]


class ClientGone(ConnectionError):
    """The client stopped reading (an answer not taken within ``WRITE_TIMEOUT_S``)."""


class HttpConnection:
    """Requests of one connection, answered in turn (see the module docstring)."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        handler: Handler,
        *,
        read_timeout_s: float,
        keep_alive_s: float = KEEP_ALIVE_S,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.handler = handler
        self.read_timeout_s = read_timeout_s
        self.keep_alive_s = keep_alive_s
        self.h11 = h11.Connection(h11.SERVER, max_incomplete_event_size=MAX_REQUEST_HEAD_BYTES)
        self.client = _address(writer, "peername")
        self.local = _address(writer, "sockname")
        #: bytes of the answer not written yet (``_send``)
        self._out: list[bytes] = []
        #: requests answered on this connection
        self.served = 0
        #: waiting for the next request of a kept-alive connection, nothing of it received:
        #: the server may close it to make room for a new connection
        self.idle = False

    def close(self) -> None:
        """Close the connection (its ``serve`` ends: the read sees the end of the stream)."""
        self.writer.close()

    async def serve(self) -> None:
        """Answer requests until the client or the protocol ends the connection."""
        while True:
            got = await self._request()
            if got is None:
                return
            if isinstance(got, Response):  # a request we refuse: answered, then closed
                return await self.refuse(got)
            await self._answer(got.method == "HEAD", await self.handler(got))
            self.served += 1
            if self.h11.our_state is not h11.DONE or self.h11.their_state is not h11.DONE:
                return  # Connection: close, HTTP/1.0, or an answer that ends the connection
            self.h11.start_next_cycle()

    async def refuse(self, answer: Response) -> None:
        """Answer ``answer`` to a request not read (whole), then close: half-closed first,
        what the client still sends taken for at most ``LINGER_S`` (closing with bytes unread
        resets the connection, and the client may lose the answer)."""
        await self._respond(answer, head_only=False, close=True)
        if self.writer.can_write_eof():  # not over TLS: its close_notify comes with the close
            self.writer.write_eof()
        with contextlib.suppress(TimeoutError, ConnectionError):
            async with asyncio.timeout(LINGER_S):
                while await self.reader.read(READ_BYTES):
                    pass

    # ------------------------------------------------------------------ reading
    async def _request(self) -> Request | Response | None:
        """The next request with its body; a Response when it is refused; None when the
        client closed the connection or a kept-alive one stayed quiet."""
        head = bytearray(self.h11.trailing_data[0])  # pipelined after the last request
        got = await self._head(head)
        if not isinstance(got, h11.Request):
            return got
        size = m.end() if (m := _HEAD_END.search(head)) else len(head)
        if size > MAX_REQUEST_HEAD_BYTES or len(got.headers) > MAX_REQUEST_HEADERS:
            return _refusal(head, HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE, "too_large",
                            f"the request head is over {MAX_REQUEST_HEAD_BYTES} bytes or "
                            f"{MAX_REQUEST_HEADERS} fields")  # fmt: skip
        target = got.target.decode("ascii", "replace")
        path, _, query = target.partition("?")
        if _repeated_length(bytes(head[:size])):  # h11 merges equal ones (RFC 9110 8.6 allows it)
            return error_answer(path, HTTPStatus.BAD_REQUEST, "bad_request", "content-length given twice")
        headers = {n.decode("latin-1"): v.decode("latin-1") for n, v in got.headers}
        if int(headers.get("content-length", "0")) > MAX_REQUEST_BODY_BYTES:
            return error_answer(path, HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "too_large",
                                f"body larger than {MAX_REQUEST_BODY_BYTES} bytes")  # fmt: skip
        body = await self._body(path)
        if isinstance(body, Response):
            return body
        return Request(
            method=got.method.decode("ascii"),
            path=urllib.parse.unquote(path),
            query={k: v[0] for k, v in urllib.parse.parse_qs(query).items()},
            headers=headers,
            body=body,
            client=self.client,
            local=self.local,
        )

    async def _head(self, head: bytearray) -> h11.Request | Response | None:
        """h11's ``Request`` event; ``head`` gets the bytes it came in (at most one byte over
        the bound: enough to tell it is over)."""
        loop = asyncio.get_running_loop()
        waiting = self.served > 0 and not head  # a kept-alive connection between requests
        deadline = None if waiting else loop.time() + self.read_timeout_s
        while True:
            try:
                event = self.h11.next_event()
            except h11.RemoteProtocolError as exc:
                return _protocol_refusal(head, exc)
            if isinstance(event, h11.Request):
                return event
            if event is not h11.NEED_DATA:
                return None  # ConnectionClosed: the client closed between requests
            self.idle = deadline is None
            try:
                async with asyncio.timeout(self.keep_alive_s if deadline is None else deadline - loop.time()):
                    data = await self.reader.read(READ_BYTES)
            except TimeoutError:
                if deadline is None:
                    return None  # quiet since its last answer: closed without a word
                return _refusal(head, HTTPStatus.REQUEST_TIMEOUT, "timeout",
                                f"the request did not arrive within {self.read_timeout_s:g} s")  # fmt: skip
            finally:
                self.idle = False
            if deadline is None:
                deadline = loop.time() + self.read_timeout_s
            head += data[: max(0, MAX_REQUEST_HEAD_BYTES + 1 - len(head))]
            self.h11.receive_data(data)  # b"": the client closed its side

    async def _body(self, path: str) -> bytes | Response:
        if self.h11.they_are_waiting_for_100_continue:  # Expect: 100-continue (curl sends it)
            self._send(h11.InformationalResponse(status_code=100, headers=[], reason=b"Continue"))
            await self._drain()
        body = bytearray()
        try:
            async with asyncio.timeout(self.read_timeout_s):
                while True:
                    event = self.h11.next_event()
                    if event is h11.NEED_DATA:
                        self.h11.receive_data(await self.reader.read(READ_BYTES))
                    elif isinstance(event, h11.Data):
                        body += event.data
                        if len(body) > MAX_REQUEST_BODY_BYTES:  # a chunked body has no length
                            return error_answer(path, HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "too_large",
                                                f"body larger than {MAX_REQUEST_BODY_BYTES} bytes")  # fmt: skip
                    elif isinstance(event, h11.EndOfMessage):
                        return bytes(body)
                    else:  # ConnectionClosed cannot come before the end of the body
                        raise h11.RemoteProtocolError("the body ended early")
        except TimeoutError:
            return error_answer(path, HTTPStatus.REQUEST_TIMEOUT, "timeout", "the body did not arrive in time")
        except h11.RemoteProtocolError as exc:
            return error_answer(path, HTTPStatus(exc.error_status_hint), "bad_request", str(exc))

    # ------------------------------------------------------------------ writing
    def _send(self, event: Any) -> None:
        """h11's bytes of ``event``, kept until ``_drain`` writes them in one piece (a head
        and its body in one segment, one system call)."""
        data = self.h11.send(event)
        if data:
            self._out.append(data)

    async def _drain(self) -> None:
        if self._out:
            self.writer.write(b"".join(self._out))
            self._out.clear()
        try:
            async with asyncio.timeout(WRITE_TIMEOUT_S):
                await self.writer.drain()
        except TimeoutError:
            raise ClientGone(f"the client took nothing for {WRITE_TIMEOUT_S:g} s") from None

    def _head_out(self, status: HTTPStatus, headers: dict[str, str]) -> None:
        fields = [(k.encode("latin-1"), v.encode("latin-1", "replace")) for k, v in headers.items()]
        self._send(h11.Response(status_code=status.value, reason=status.phrase.encode(), headers=fields))

    async def _answer(self, head_only: bool, answer: Answer) -> None:
        if isinstance(answer, Response):
            return await self._respond(answer, head_only=head_only)
        headers = {"Content-Type": answer.content_type, "Cache-Control": "no-store"}
        if isinstance(answer, Chunked):
            return await self._chunked(answer, {**headers, **answer.headers}, head_only)
        # a Stream: no length (h11 makes it chunked for HTTP/1.1), closed after its body
        self._head_out(HTTPStatus.OK, {**headers, "Connection": "close", **answer.headers})
        await self._drain()
        if head_only:
            self._send(h11.EndOfMessage())
            return await self._drain()
        gone = asyncio.ensure_future(self.reader.read(1))  # an event source sends nothing
        try:
            await answer.body(StreamOut(self.writer, gone, lambda d: self.h11.send(h11.Data(data=d)) or b""))
            if not gone.done() and not self.writer.transport.is_closing():
                self._send(h11.EndOfMessage())
                await self._drain()
        finally:
            gone.cancel()

    async def _respond(self, answer: Response, *, head_only: bool, close: bool = False) -> None:
        if self.h11.our_state not in (h11.IDLE, h11.SEND_RESPONSE):
            return  # an answer is already under way: only closing is left
        headers = {
            "Content-Type": answer.content_type,
            "Content-Length": str(len(answer.body)),
            "Cache-Control": "no-store",
            **answer.headers,
        }
        if close:
            headers["Connection"] = "close"
        self._head_out(answer.status, headers)
        if answer.body and not head_only:
            self._send(h11.Data(data=answer.body))
        self._send(h11.EndOfMessage())
        await self._drain()

    async def _chunked(self, answer: Chunked, headers: dict[str, str], head_only: bool) -> None:
        chunks = answer.chunks
        try:
            self._head_out(HTTPStatus.OK, headers)  # no length: chunked for HTTP/1.1
            await self._drain()
            if not head_only:
                async for data in chunks:
                    if data:
                        self._send(h11.Data(data=data))
                        await self._drain()  # the client reads it: memory stays constant
            self._send(h11.EndOfMessage())
            await self._drain()
        finally:
            aclose = getattr(chunks, "aclose", None)
            if aclose is not None:
                await aclose()


def _repeated_length(head: bytes) -> bool:
    """Content-Length given in two fields, or as a list in one (``2, 2``): h11 takes equal
    values as one; we refuse them (RFC 9112 6.3: a sign of request smuggling)."""
    values = [
        value
        for name, _, value in (line.partition(b":") for line in head.split(b"\n")[1:])
        if name.strip().lower() == b"content-length"
    ]
    return len(values) > 1 or any(b"," in v for v in values)


def _path_of(head: bytes | bytearray) -> str:
    """The path of a request line, as far as it came ("" when there is none)."""
    parts = bytes(head).split(b"\n", 1)[0].split(b" ")
    return parts[1].decode("ascii", "replace") if len(parts) >= 2 else ""


def _refusal(head: bytes | bytearray, status: HTTPStatus, kind: str, message: str) -> Response:
    return error_answer(_path_of(head), status, kind, message)


def _protocol_refusal(head: bytes | bytearray, exc: h11.RemoteProtocolError) -> Response:
    """h11's refusal of a request: its status (400; 431 for a head over the bound; 501 for a
    transfer coding other than chunked) and its words."""
    status = HTTPStatus(exc.error_status_hint)
    kind = "too_large" if status == HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE else "bad_request"
    return _refusal(head, status, kind, f"bad request: {exc}")


def _address(writer: asyncio.StreamWriter, which: str) -> str:
    peer = writer.get_extra_info(which)
    return str(peer[0]) if isinstance(peer, tuple) and peer else ""
