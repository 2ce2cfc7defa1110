"""SDO server protocol of a simulated node (DS-301 7.2.4, SGH10 manual 4.4.1): sans-I/O.

Request bytes in, response bytes out. Supports expedited and segmented upload and download;
block transfer and unknown command specifiers are aborted with 0x05040001. What a read returns
and whether a write is accepted is decided by the two callables given by the node, which raise
``SdoAbortError`` to refuse. Transfers left unfinished for ``timeout_s`` are aborted with
0x05040000 by ``poll``.

Command bytes (first byte of the 8-byte frame, DS-301 / SGH10 manual Tables 6 and 7):
  client: 0x2_ initiate download (e bit 1, s bit 0, n bits 2-3), 0x0_/0x1_ download segment
          (toggle bit 4, n bits 1-3, c bit 0), 0x40 initiate upload, 0x60/0x70 upload segment,
          0x80 abort
  server: 0x60 download response, 0x20/0x30 download segment response, 0x4F/0x4B/0x47/0x43
          expedited upload (1..4 bytes), 0x41 segmented upload with size, 0x0_/0x1_ upload
          segment, 0x80 abort

Imports: canopen_gateway.sim.objects only.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

from canopen_gateway.sim.objects import (
    ABORT_COMMAND,
    ABORT_LENGTH,
    ABORT_TIMEOUT,
    ABORT_TOGGLE,
    SdoAbortError,
)

ReadFn = Callable[[int, int], bytes]
WriteFn = Callable[[int, int, bytes, bool], None]  # (index, sub, data, size indicated)


def abort_frame(index: int, sub: int, code: int) -> bytes:
    """DS-301 abort transfer: 0x80, index LE, sub, abort code LE (SGH10 manual 4.4.1.3)."""
    return struct.pack("<BHBI", 0x80, index, sub, code)


@dataclass
class _Transfer:
    upload: bool
    index: int
    sub: int
    toggle: int = 0
    data: bytearray | bytes = b""
    pos: int = 0
    size: int | None = None
    last_s: float = 0.0


class SdoServer:
    """One SDO server channel (the default 0x600+id / 0x580+id pair)."""

    def __init__(
        self,
        read: ReadFn,
        write: WriteFn,
        *,
        timeout_s: float = 1.0,
        segment_upload_command: int | None = None,
        expedited_only: bool = False,
    ) -> None:
        self._read = read
        self._write = write
        self.timeout_s = timeout_s
        # A device whose manual shows a fixed command byte in every upload segment response
        # (SGH10 manual 4.4.1.4 shows 03h for the last segment of 5 bytes); None = DS-301.
        self.segment_upload_command = segment_upload_command
        # AP05 manual 5.4.1: "exclusively via expedited Request/Response"
        self.expedited_only = expedited_only
        self._transfer: _Transfer | None = None

    @property
    def busy(self) -> bool:
        return self._transfer is not None

    def reset(self) -> None:
        self._transfer = None

    def poll(self, now: float) -> bytes | None:
        """Abort an unfinished transfer after ``timeout_s`` without a request."""
        t = self._transfer
        if t is not None and now - t.last_s > self.timeout_s:
            self._transfer = None
            return abort_frame(t.index, t.sub, ABORT_TIMEOUT)
        return None

    def on_request(self, data: bytes, now: float) -> bytes | None:
        """The response to one request frame (None for a client abort)."""
        data = bytes(data).ljust(8, b"\0")
        cmd = data[0]
        ccs = cmd >> 5
        index, sub = struct.unpack_from("<HB", data, 1)
        try:
            if ccs == 1:
                return self._initiate_download(cmd, index, sub, data, now)
            if ccs == 0:
                return self._download_segment(cmd, data, now)
            if ccs == 2:
                return self._initiate_upload(index, sub, now)
            if ccs == 3:
                return self._upload_segment(cmd, now)
            if ccs == 4:
                self._transfer = None
                return None
            raise SdoAbortError(ABORT_COMMAND, f"command byte 0x{cmd:02X}")
        except SdoAbortError as exc:
            t = self._transfer
            self._transfer = None
            if ccs in (0, 3) and t is not None:
                index, sub = t.index, t.sub
            elif ccs in (0, 3):
                index, sub = 0, 0
            return abort_frame(index, sub, exc.code)

    # -- download ----------------------------------------------------------------------------
    def _initiate_download(self, cmd: int, index: int, sub: int, data: bytes, now: float) -> bytes:
        self._transfer = None
        expedited = bool(cmd & 0x02)
        size_given = bool(cmd & 0x01)
        if not expedited and self.expedited_only:
            raise SdoAbortError(ABORT_COMMAND, "segmented transfer not supported")
        if expedited:
            n = (cmd >> 2) & 0x03 if size_given else 0
            self._write(index, sub, data[4 : 8 - n], size_given)
        else:
            size = struct.unpack_from("<I", data, 4)[0] if size_given else None
            self._transfer = _Transfer(False, index, sub, data=bytearray(), size=size, last_s=now)
        return struct.pack("<BHB4x", 0x60, index, sub)

    def _download_segment(self, cmd: int, data: bytes, now: float) -> bytes:
        t = self._transfer
        if t is None or t.upload:
            raise SdoAbortError(ABORT_COMMAND, "download segment without a transfer")
        toggle = (cmd >> 4) & 1
        if toggle != t.toggle:
            raise SdoAbortError(ABORT_TOGGLE)
        n = (cmd >> 1) & 0x07
        assert isinstance(t.data, bytearray)
        t.data += data[1 : 8 - n]
        t.last_s = now
        t.toggle ^= 1
        response = bytes([0x20 | (toggle << 4)]) + bytes(7)
        if cmd & 0x01:
            self._transfer = None
            if t.size is not None and t.size != len(t.data):
                raise SdoAbortError(ABORT_LENGTH, f"{len(t.data)} bytes, {t.size} announced")
            self._write(t.index, t.sub, bytes(t.data), True)
        return response

    # -- upload ------------------------------------------------------------------------------
    def _initiate_upload(self, index: int, sub: int, now: float) -> bytes:
        self._transfer = None
        value = self._read(index, sub)
        if len(value) > 4 and self.expedited_only:
            raise SdoAbortError(ABORT_COMMAND, "segmented transfer not supported")
        if 0 < len(value) <= 4:
            cmd = 0x43 | ((4 - len(value)) << 2)
            return struct.pack("<BHB", cmd, index, sub) + value.ljust(4, b"\0")
        self._transfer = _Transfer(True, index, sub, data=value, size=len(value), last_s=now)
        return struct.pack("<BHBI", 0x41, index, sub, len(value))

    def _upload_segment(self, cmd: int, now: float) -> bytes:
        t = self._transfer
        if t is None or not t.upload:
            raise SdoAbortError(ABORT_COMMAND, "upload segment without a transfer")
        toggle = (cmd >> 4) & 1
        if toggle != t.toggle:
            raise SdoAbortError(ABORT_TOGGLE)
        chunk = t.data[t.pos : t.pos + 7]
        t.pos += len(chunk)
        t.toggle ^= 1
        t.last_s = now
        last = t.pos >= len(t.data)
        if last:
            self._transfer = None
        if last and self.segment_upload_command is not None:
            out = (self.segment_upload_command & ~0x10) | (toggle << 4)
        else:
            out = (toggle << 4) | ((7 - len(chunk)) << 1) | (1 if last else 0)
        return bytes([out]) + bytes(chunk).ljust(7, b"\0")
