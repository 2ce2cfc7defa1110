"""What the HTTP server and its app (the web console) hand each other: a parsed ``Request``, and
one of three answers: a ``Response`` (a body of known length), a ``Chunked`` answer (HTTP/1.1
chunked encoding, each chunk written and drained before the next is asked for: an export of
any length in constant memory) or a ``Stream`` (server-sent events: its body writes to a
``StreamOut`` until the client goes away; the connection is closed after it).

No sockets and no protocol here: ``connection.py`` frames these on the wire (by h11).

Imports: the standard library only.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Any, Protocol

JSON_TYPE = "application/json"
TEXT_TYPE = "text/plain; charset=utf-8"


@dataclass(frozen=True)
class Request:
    """One parsed request for an ``app``: header names lower-case, the first value of each
    query parameter."""

    method: str
    path: str
    query: Mapping[str, str] = field(default_factory=dict)
    headers: Mapping[str, str] = field(default_factory=dict)
    body: bytes = b""
    client: str = ""  # the peer's address (per-client limits of the app)
    local: str = ""  # the address the request arrived at (the app's Host check)


@dataclass(frozen=True)
class Response:
    status: HTTPStatus
    body: bytes = b""
    content_type: str = TEXT_TYPE
    headers: Mapping[str, str] = field(default_factory=dict)


class _Writer(Protocol):
    """The part of ``asyncio.StreamWriter`` a stream writes through."""

    @property
    def transport(self) -> Any: ...

    def write(self, data: bytes) -> None: ...


class StreamOut:
    """What a ``Stream`` body writes to: each ``write`` goes out as one piece of the answer
    (``frame`` makes it an HTTP/1.1 chunk); ``buffered()`` is what the client has not taken
    yet (a body skips or drops a client that does not read); ``gone`` is done once the client
    went away (it closed its side, or sent anything: a browser's event source sends nothing)."""

    def __init__(
        self,
        writer: _Writer,
        gone: asyncio.Future[Any],
        frame: Callable[[bytes], bytes] = bytes,
    ) -> None:
        self._writer = writer
        self._frame = frame
        self.gone = gone

    def write(self, data: bytes) -> None:
        if data:
            self._writer.write(self._frame(data))

    def buffered(self) -> int:
        """Bytes written that the socket has not sent yet."""
        return int(self._writer.transport.get_write_buffer_size())

    def closing(self) -> bool:
        """The connection is closing (or closed): nothing written arrives any more."""
        return bool(self._writer.transport.is_closing())


StreamBody = Callable[[StreamOut], Awaitable[None]]


@dataclass(frozen=True)
class Stream:
    """An answer without a length: the headers, then ``body(out)`` writes until it returns
    (e.g. the client went away); the connection is closed after."""

    content_type: str
    body: StreamBody
    headers: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Chunked:
    """An answer of unknown length in HTTP/1.1 chunked encoding: the headers, then each bytes
    ``chunks`` yields as one chunk (written and drained before the next is asked for), then the
    last chunk. The iterator is closed when the client goes away."""

    content_type: str
    chunks: AsyncIterator[bytes]
    headers: Mapping[str, str] = field(default_factory=dict)


Answer = Response | Stream | Chunked
App = Callable[[Request], Awaitable[Answer | None]]


def error_answer(path: str, status: HTTPStatus, kind: str, message: str,
                 headers: Mapping[str, str] | None = None) -> Response:  # fmt: skip
    """An error the server answers itself: under ``/api/`` a JSON document with ``error`` and
    ``message``, as the API's own errors; elsewhere one line of text."""
    if path.startswith("/api/"):
        body = json.dumps({"error": kind, "message": message}).encode() + b"\n"
        return Response(status, body, JSON_TYPE, headers or {})
    return Response(status, message.encode() + b"\n", TEXT_TYPE, headers or {})
