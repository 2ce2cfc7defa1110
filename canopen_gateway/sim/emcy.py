"""EMCY producer of a simulated node (DS-301 7.2.7, SGH10 manual 4.5.1): sans-I/O.

Keeps the set of active errors, the error register 1001h, the pre-defined error field 1003h
(newest in sub 1, count in sub 0) and the inhibit time 1015h (100 us units) between EMCY frames.
An EMCY frame is 8 bytes: error code u16 LE, error register 1001h, 5 manufacturer bytes. An error
is signalled once when it appears; when one goes away, code 0000h is sent with the error
register of the errors that remain. Whether a frame may go out (NMT state, 1014h bit 31) is the
node's decision.

Imports: canopen_gateway.sim.objects.
"""

from __future__ import annotations

import struct
from collections import deque

from canopen_gateway.sim.objects import ObjectValues

ERROR_RESET = 0x0000  # DS-301: error reset or no error (SGH10 manual Table 9)
REGISTER_GENERIC = 0x01  # DS-301 1001h bit 0: generic error, set while any error is active


def frame_data(code: int, register: int, mfr: bytes = b"") -> bytes:
    return struct.pack("<HB", code & 0xFFFF, register & 0xFF) + bytes(mfr[:5]).ljust(5, b"\0")


class EmcyProducer:
    """Active errors, 1001h/1003h bookkeeping and the 1015h inhibit queue."""

    def __init__(self, values: ObjectValues) -> None:
        self.values = values
        self.active: dict[int, tuple[int, bytes]] = {}
        subs = [s for (i, s) in values.vars if i == 0x1003 and s > 0]
        self.history_size = max(subs) if subs else 0
        self._queue: deque[bytes] = deque()
        self._last_sent_s: float | None = None
        self.sent = 0

    def reset(self) -> None:
        """Power-on: no active error, empty queue (1003h is reloaded by the node)."""
        self.active.clear()
        self._queue.clear()
        self._last_sent_s = None
        self._write_register()

    @property
    def error_register(self) -> int:
        reg = 0
        for bits, _ in self.active.values():
            reg |= bits
        return reg | REGISTER_GENERIC if self.active else 0

    def _write_register(self) -> None:
        if self.values.has(0x1001, 0):
            self.values.set(0x1001, 0, self.error_register)

    def _add_history(self, code: int, mfr: bytes) -> None:
        if not self.history_size:
            return
        count = int(self.values.get(0x1003, 0, 0))
        entries = [int(self.values.get(0x1003, s, 0)) for s in range(1, count + 1)]
        # DS-301 1003h: bits 0-15 error code, bits 16-31 manufacturer-specific information
        info = int.from_bytes(bytes(mfr[:2]).ljust(2, b"\0"), "little")
        entries.insert(0, (info << 16) | (code & 0xFFFF))
        entries = entries[: self.history_size]
        for s, value in enumerate(entries, start=1):
            self.values.set(0x1003, s, value)
        self.values.set(0x1003, 0, len(entries))

    def clear_history(self) -> None:
        """1003h:00 written with 0 (SGH10 manual 4.7.2.4)."""
        for s in range(1, self.history_size + 1):
            self.values.set(0x1003, s, 0)
        if self.history_size:
            self.values.set(0x1003, 0, 0)

    def raise_error(self, code: int, register: int = 0, mfr: bytes = b"") -> bytes | None:
        """Record an error; the EMCY data to send, or None if it was already active."""
        if code in self.active:
            return None
        self.active[code] = (register & 0xFF, bytes(mfr))
        self._write_register()
        self._add_history(code, mfr)
        return frame_data(code, self.error_register, mfr)

    def clear_error(self, code: int) -> bytes | None:
        """Forget an error; the EMCY 0000h data to send, or None if it was not active."""
        if self.active.pop(code, None) is None:
            return None
        self._write_register()
        return frame_data(ERROR_RESET, self.error_register)

    # -- inhibit time 1015h ------------------------------------------------------------------
    def _inhibit_s(self) -> float:
        return int(self.values.get(0x1015, 0, 0)) * 100e-6

    def queue(self, data: bytes) -> None:
        self._queue.append(data)

    def poll(self, now: float) -> list[bytes]:
        """Frames whose turn has come under the inhibit time."""
        out: list[bytes] = []
        inhibit_s = self._inhibit_s()
        while self._queue:
            if self._last_sent_s is not None and inhibit_s > 0:
                if now < self._last_sent_s + inhibit_s:
                    break
            out.append(self._queue.popleft())
            self._last_sent_s = now
            self.sent += 1
            if inhibit_s > 0:
                break
        return out
