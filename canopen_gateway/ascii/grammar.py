"""The lexical level of the CiA 309-3 ASCII language, sans-I/O: the internal error codes
(``Iec``), request lines out of a byte stream (``LineSplitter``: CR LF or LF, a line over
``MAX_LINE_BYTES`` refused whole), the sequence number of a line, and its tokens (``tokenize``:
``#`` comments, quoted visible strings).

Imports: canopen_gateway.canopen.code_text (the base of ``Iec``) and the standard library. Nothing of bus/,
commands or a transport.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from canopen_gateway.canopen.code_text import CodeText

#: a request line longer than this (without its line end) is refused with ERROR:101
MAX_LINE_BYTES = 1024


class Iec(CodeText):
    """CiA 309-3 internal error codes (the answer ``ERROR:<code>``; 2xx also in events), each
    with its text (``Iec.TIMEOUT.text``: "Time-out")."""

    REQUEST_NOT_SUPPORTED = 100, "Request not supported"
    SYNTAX = 101, "Syntax error"
    INTERNAL_STATE = 102, "Request not processed due to internal state"
    TIMEOUT = 103, "Time-out"
    NO_DEFAULT_NET = 104, "No default net set"
    NO_DEFAULT_NODE = 105, "No default node set"
    UNSUPPORTED_NET = 106, "Unsupported net"
    UNSUPPORTED_NODE = 107, "Unsupported node"
    LOST_GUARDING = 200, "Lost guarding message"
    LOST_CONNECTION = 201, "Lost connection"
    HEARTBEAT_STARTED = 202, "Heartbeat started"
    HEARTBEAT_LOST = 203, "Heartbeat lost"
    WRONG_NMT_STATE = 204, "Wrong NMT state"
    BOOT_UP = 205, "Boot-up"


class LineSplitter:
    """Bytes of a TCP stream -> request lines (str, CR LF or LF removed).

    A line longer than ``MAX_LINE_BYTES`` yields one ``Overlong`` (with the sequence number its
    start carried, if any) and the rest of it up to the next LF is discarded: the connection
    goes on with the next line. Bytes that are not ASCII are kept as U+FFFD (a syntax error)."""

    def __init__(self, max_bytes: int = MAX_LINE_BYTES) -> None:
        self.max_bytes = max_bytes
        self._buf = bytearray()
        self._discarding = False

    def feed(self, data: bytes) -> list[str | Overlong]:
        out: list[str | Overlong] = []
        self._buf += data
        while True:
            nl = self._buf.find(b"\n")
            if self._discarding:
                if nl < 0:
                    self._buf.clear()
                    return out
                del self._buf[: nl + 1]
                self._discarding = False
                continue
            if nl < 0:
                if len(self._buf) > self.max_bytes:
                    out.append(Overlong(peek_seq(self._buf)))
                    self._buf.clear()
                    self._discarding = True
                return out
            line = bytes(self._buf[:nl])
            del self._buf[: nl + 1]
            if line.endswith(b"\r"):
                line = line[:-1]
            if len(line) > self.max_bytes:
                out.append(Overlong(peek_seq(line)))
                continue
            out.append(line.decode("ascii", errors="replace"))


@dataclass(frozen=True)
class Overlong:
    """A request line longer than ``MAX_LINE_BYTES``."""

    seq: int | None


_SEQ_RE = re.compile(rb"^\s*\[([0-9]{1,10})\]")


def peek_seq(line: bytes | bytearray | str) -> int | None:
    raw = line.encode("ascii", errors="replace") if isinstance(line, str) else bytes(line)
    m = _SEQ_RE.match(raw)
    if m is None:
        return None
    v = int(m.group(1))
    return v if v <= 0xFFFFFFFF else None


class RequestError(Exception):
    """A request answered with an internal error code."""

    def __init__(self, seq: int | None, code: Iec, why: str = ""):
        self.seq, self.code, self.why = seq, code, why
        super().__init__(f"{int(code)} {code.text}" + (f": {why}" if why else ""))


def tokenize(line: str) -> list[str]:
    """Split on blanks; a token starting with ``"`` runs to the closing quote (``""`` inside is
    one quote); ``#`` where a token starts begins a comment. ValueError when a quote is open."""
    tokens: list[str] = []
    i, n = 0, len(line)
    while i < n:
        c = line[i]
        if c in " \t":
            i += 1
            continue
        if c == "#":
            break
        if c == '"':
            i += 1
            buf: list[str] = []
            while True:
                if i >= n:
                    raise ValueError("unterminated quote")
                if line[i] == '"':
                    if i + 1 < n and line[i + 1] == '"':
                        buf.append('"')
                        i += 2
                        continue
                    i += 1
                    break
                buf.append(line[i])
                i += 1
            if i < n and line[i] not in " \t":
                raise ValueError("a quoted token must end with a blank")
            tokens.append("".join(buf))
            continue
        j = i
        while j < n and line[j] not in " \t":
            j += 1
        tokens.append(line[i:j])
        i = j
    return tokens
