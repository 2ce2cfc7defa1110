"""The SDO client side of one transfer, as a plain state machine (CiA 301 7.2.4.3; SGH10
manual 4.4.1, AP05 manual 5.4.1 with their worked examples).

Rule 1: everything about the bytes of an SDO transfer lives here: expedited and segmented
upload and download, the toggle bit, retries of an unanswered request, and the abort frame the
client sends, which names the object of the transfer (index and sub-index) and the reason.
Rule 2: no I/O and no clock. The owner (``bus.node.node.Node``) calls ``start(now)``, feeds every
frame received on 580h + node id with ``on_response(data, now)`` and calls ``poll(now)`` at
``next_deadline()``; each returns the request frames (8 bytes for 600h + node id) to send.
When ``done`` is true, ``result`` holds the uploaded bytes (``b""`` for a download) or
``abort_code`` the reason (the server's abort, or the client's own such as 05040000h
"SDO protocol timed out").

==================  ======================================  ==================  ====================
state               event                                   next                frames / outcome
==================  ======================================  ==================  ====================
IDLE                start, upload                           UP_INIT             initiate upload 40h
IDLE                start, download <= 4 bytes              DOWN_INIT           expedited 23h..2Fh
IDLE                start, download > 4 bytes               DOWN_INIT           initiate 21h + size
UP_INIT             response 4xh expedited                  DONE                result = data
UP_INIT             response 41h (size indicated)           UP_SEG              upload segment 60h
UP_SEG              segment, toggle ok, not last            UP_SEG              next segment (toggle)
UP_SEG              segment, toggle ok, last (c = 1)        DONE                result = all data
DOWN_INIT           response 60h, expedited                 DONE                result = b""
DOWN_INIT           response 60h, segmented                 DOWN_SEG            first segment
DOWN_SEG            response 2xh, toggle ok, more data      DOWN_SEG            next segment
DOWN_SEG            response 2xh, toggle ok, all sent       DONE                result = b""
any active          abort 80h from the server               DONE                abort_code = server's
any active          wrong command / toggle / object         DONE                abort frame sent
any active          poll, no answer within timeout          same (retry)        same request again
any active          poll, no answer, retries used up        DONE                abort 05040000h sent
any active          cancel                                  DONE                abort frame sent
==================  ======================================  ==================  ====================

A retry repeats only an initiate request (a segment repeated could be taken twice).

The table is data the code reads: ``RESPONSES`` (per phase, the server command specifier it
expects and the method that handles it) and ``PHASE_CHANGES`` (every phase change). An answer
with another command specifier is the server's protocol error: the transfer is aborted
(05040001h) and it is counted (``protocol_errors``); a phase change the table does not define
is a bug of ours and raises ``SdoStateError``.

Imports: canopen_gateway.canopen.cia301 (the command specifiers) and the standard library.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from enum import StrEnum

from canopen_gateway.canopen.cia301 import SdoCcs, SdoScs

# CiA 301 table 22: abort codes the client itself sends
ABORT_TOGGLE = 0x05030000  # toggle bit not alternated
ABORT_TIMEOUT = 0x05040000  # SDO protocol timed out
ABORT_COMMAND = 0x05040001  # client/server command specifier not valid or unknown
ABORT_GENERAL = 0x08000000  # general error (used for a cancelled transfer)


class SdoPhase(StrEnum):
    IDLE = "idle"
    UP_INIT = "upload-initiate"
    UP_SEG = "upload-segment"
    DOWN_INIT = "download-initiate"
    DOWN_SEG = "download-segment"
    DONE = "done"


_P = SdoPhase
#: every phase change of a transfer (the table of the module docstring)
PHASE_CHANGES: frozenset[tuple[SdoPhase, SdoPhase]] = frozenset(
    {
        (_P.IDLE, _P.UP_INIT),
        (_P.IDLE, _P.DOWN_INIT),
        (_P.IDLE, _P.DONE),  # cancelled before it started
        (_P.UP_INIT, _P.UP_SEG),
        (_P.UP_INIT, _P.DONE),
        (_P.UP_SEG, _P.DONE),
        (_P.DOWN_INIT, _P.DOWN_SEG),
        (_P.DOWN_INIT, _P.DONE),
        (_P.DOWN_SEG, _P.DONE),
    }
)


class SdoStateError(RuntimeError):
    """Our own misuse of a transfer: a phase change ``PHASE_CHANGES`` does not define."""


def abort_frame(index: int, sub: int, code: int) -> bytes:
    """CiA 301 7.2.4.3.17: abort transfer, naming the object."""
    return struct.pack("<BHBI", SdoCcs.ABORT, index, sub, code)


class SdoTransfer:
    """One client transfer of object ``index:sub``; ``data`` None = upload, bytes = download."""

    def __init__(
        self,
        index: int,
        sub: int,
        data: bytes | None = None,
        *,
        timeout_s: float = 0.5,
        retries: int = 1,
    ):
        if timeout_s <= 0:
            raise ValueError("timeout_s must be > 0")
        self.index = index
        self.sub = sub
        self.data = data
        self.timeout_s = timeout_s
        self.retries = retries
        self.phase = SdoPhase.IDLE
        self.result: bytes | None = None
        self.abort_code: int | None = None
        self.aborted_by_server = False
        self.timed_out = False
        self.started_s: float | None = None  # when the first request went out (``now``)
        self._request = b""
        self._deadline: float | None = None
        self._tries = 0
        self._toggle = 0
        self._buf = bytearray()
        self._sent = 0  # bytes of a segmented download sent so far
        self._size: int | None = None  # size a segmented upload announced
        #: answers of the server that broke the protocol (wrong command specifier or toggle)
        self.protocol_errors = 0

    # -- queries
    @property
    def done(self) -> bool:
        return self.phase is SdoPhase.DONE

    @property
    def is_upload(self) -> bool:
        return self.data is None

    def next_deadline(self) -> float | None:
        return None if self.done else self._deadline

    # -- events
    def start(self, now: float) -> list[bytes]:
        if self.phase is not SdoPhase.IDLE:
            return []
        self.started_s = now
        head = struct.pack("<HB", self.index, self.sub)
        if self.data is None:
            self._enter(SdoPhase.UP_INIT)
            return self._send(bytes([SdoCcs.INITIATE_UPLOAD]) + head + b"\0\0\0\0", now)
        self._enter(SdoPhase.DOWN_INIT)
        n = len(self.data)
        if 0 < n <= 4:  # expedited, size indicated: e = 1, s = 1, n = 4 - size
            cmd = SdoCcs.INITIATE_DOWNLOAD | ((4 - n) << 2) | 0x03
            return self._send(bytes([cmd]) + head + self.data.ljust(4, b"\0"), now)
        cmd = SdoCcs.INITIATE_DOWNLOAD | 0x01  # segmented, size indicated
        return self._send(bytes([cmd]) + head + struct.pack("<I", n), now)

    def on_response(self, data: bytes, now: float) -> list[bytes]:
        if self.done or self.phase is SdoPhase.IDLE or len(data) < 1:
            return []
        data = bytes(data).ljust(8, b"\0")
        cmd = data[0]
        if cmd == SdoScs.ABORT:
            index, sub, code = struct.unpack_from("<HBI", data, 1)
            if (index, sub) != (self.index, self.sub) and self.phase in (
                SdoPhase.UP_INIT,
                SdoPhase.DOWN_INIT,
            ):
                return []  # an abort of another transfer (e.g. another client's)
            self.aborted_by_server = True
            return self._finish(code)
        expected, handle = RESPONSES[self.phase]
        if cmd & 0xE0 != expected:
            self.protocol_errors += 1
            return self._abort(ABORT_COMMAND)
        return handle(self, cmd, data, now)

    # -- the rows of the table, one method per phase (``RESPONSES``)
    def _on_upload_initiate(self, cmd: int, data: bytes, now: float) -> list[bytes]:
        if struct.unpack_from("<HB", data, 1) != (self.index, self.sub):
            return []  # not the answer to our request
        if cmd & 0x02:  # expedited
            size = 4 - ((cmd >> 2) & 0x03) if cmd & 0x01 else 4
            return self._succeed(data[4 : 4 + size])
        self._enter(SdoPhase.UP_SEG)
        self._toggle = 0
        self._size = struct.unpack_from("<I", data, 4)[0] if cmd & 0x01 else None
        return self._send(bytes([SdoCcs.UPLOAD_SEGMENT]) + b"\0" * 7, now)

    def _on_upload_segment(self, cmd: int, data: bytes, now: float) -> list[bytes]:
        if (cmd >> 4) & 1 != self._toggle:
            self.protocol_errors += 1
            return self._abort(ABORT_TOGGLE)
        size = 7 - ((cmd >> 1) & 0x07)
        self._buf += data[1 : 1 + size]
        if cmd & 0x01:  # c: no more segments; the size indicated at initiate wins
            size_ok = self._buf if self._size is None else self._buf[: self._size]
            return self._succeed(bytes(size_ok))
        self._toggle ^= 1
        return self._send(bytes([SdoCcs.UPLOAD_SEGMENT | (self._toggle << 4)]) + b"\0" * 7, now)

    def _on_download_initiate(self, cmd: int, data: bytes, now: float) -> list[bytes]:
        if struct.unpack_from("<HB", data, 1) != (self.index, self.sub):
            return []
        assert self.data is not None
        if 0 < len(self.data) <= 4:
            return self._succeed(b"")
        self._enter(SdoPhase.DOWN_SEG)
        self._toggle = 0
        return self._next_segment(now)

    def _on_download_segment(self, cmd: int, data: bytes, now: float) -> list[bytes]:
        if (cmd >> 4) & 1 != self._toggle:
            self.protocol_errors += 1
            return self._abort(ABORT_TOGGLE)
        assert self.data is not None
        if self._sent >= len(self.data):
            return self._succeed(b"")
        self._toggle ^= 1
        return self._next_segment(now)

    def poll(self, now: float) -> list[bytes]:
        if self.done or self._deadline is None or now <= self._deadline:
            return []
        if self._tries <= self.retries and self.phase in (SdoPhase.UP_INIT, SdoPhase.DOWN_INIT):
            return self._send(self._request, now)
        self.timed_out = True
        return self._abort(ABORT_TIMEOUT)

    def cancel(self, code: int = ABORT_GENERAL, *, send_abort: bool = True) -> list[bytes]:
        """End the transfer now (e.g. the node rebooted); an abort frame unless told not to."""
        if self.done:
            return []
        if self.phase is SdoPhase.IDLE or not send_abort:
            self._finish(code)
            return []
        return self._abort(code)

    # -- internals
    def _next_segment(self, now: float) -> list[bytes]:
        assert self.data is not None
        chunk = self.data[self._sent : self._sent + 7]
        self._sent += len(chunk)
        last = 1 if self._sent >= len(self.data) else 0
        cmd = SdoCcs.DOWNLOAD_SEGMENT | (self._toggle << 4) | ((7 - len(chunk)) << 1) | last
        return self._send(bytes([cmd]) + chunk.ljust(7, b"\0"), now)

    def _send(self, frame: bytes, now: float) -> list[bytes]:
        if frame is not self._request:
            self._tries = 0
        self._request = frame
        self._tries += 1
        self._deadline = now + self.timeout_s
        return [frame]

    def _enter(self, phase: SdoPhase) -> None:
        if (self.phase, phase) not in PHASE_CHANGES:
            raise SdoStateError(f"no phase change from {self.phase} to {phase}")
        self.phase = phase

    def _succeed(self, result: bytes) -> list[bytes]:
        self.result = result
        self._enter(SdoPhase.DONE)
        self._deadline = None
        return []

    def _finish(self, code: int) -> list[bytes]:
        self.abort_code = code
        self._enter(SdoPhase.DONE)
        self._deadline = None
        return []

    def _abort(self, code: int) -> list[bytes]:
        self._finish(code)
        return [abort_frame(self.index, self.sub, code)]


_Handler = Callable[[SdoTransfer, int, bytes, float], list[bytes]]
#: phase -> (the server command specifier it expects, the method for it): the rows of the table
RESPONSES: dict[SdoPhase, tuple[int, _Handler]] = {
    SdoPhase.UP_INIT: (SdoScs.INITIATE_UPLOAD, SdoTransfer._on_upload_initiate),
    SdoPhase.UP_SEG: (SdoScs.UPLOAD_SEGMENT, SdoTransfer._on_upload_segment),
    SdoPhase.DOWN_INIT: (SdoScs.INITIATE_DOWNLOAD, SdoTransfer._on_download_initiate),
    SdoPhase.DOWN_SEG: (SdoScs.DOWNLOAD_SEGMENT, SdoTransfer._on_download_segment),
}
