"""CiA 305 LSS Fast Scan, the master's side: finding the LSS address (1018h:01..04: vendor id,
product code, revision number, serial number) of an unconfigured slave whose serial number is
not known, bit by bit, so identical devices can be given node ids without reading labels.

The frame (7E5h): ``51h``, IDNumber (UNSIGNED32 LE, bytes 1-4), BitChecked (byte 5), LSSSub
(byte 6), LSSNext (byte 7). Every unconfigured slave in LSS waiting whose part ``LSSSub`` of its
address equals IDNumber in bits 31..BitChecked answers ``4Fh`` (identify slave) on 7E4h and
takes ``LSSNext`` as the part it compares next; ``BitChecked`` 80h resets every unconfigured
slave to part 0 and all answer. A slave matching in full (BitChecked 0 on the last part, LSSNext
back to 0) enters LSS configuration.

    reset                  (0, 80h, 0, 0)           no answer: no unconfigured slave, done
    per part p (0..3):
      per bit b 31..0      (id[p], b, p, p)         no answer: bit b of id[p] is 1
      confirm              (id[p], 0, p, p+1 mod 4) no answer: the slave went away (failed)
    after part 3           the slave with the lowest address is in configuration state

A part given in advance (the vendor id and product code of a known device) is confirmed at once
without its 32 bit steps. The ``answered`` of a step is whether any 4Fh came within the
caller's wait: several slaves answering together is one answer.

Rule 1: no I/O, no clock (``next_frame`` / ``answered`` only). Rule 2: the frames are laid out
here, the command specifiers are ``canopen_gateway.canopen.cia305``'s.

Imports: canopen_gateway.canopen.cia305 and the standard library.
"""

from __future__ import annotations

import struct

from canopen_gateway.canopen.cia305 import CS_FAST_SCAN, FAST_SCAN_RESET

PARTS = ("vendor id", "product code", "revision number", "serial number")


def fast_scan_frame(id_number: int, bit_checked: int, sub: int, next_sub: int) -> bytes:
    """51h IDNumber BitChecked LSSSub LSSNext (CiA 305 Fast Scan)."""
    return struct.pack("<BIBBB", CS_FAST_SCAN, id_number & 0xFFFFFFFF, bit_checked, sub, next_sub)


class FastScan:
    """One Fast Scan: the frames to send and what each step's answer (or silence) means."""

    def __init__(self, known: tuple[int | None, int | None, int | None, int | None] = (None,) * 4):
        self.known = known
        self.ids = [k or 0 for k in known]
        self.sub = 0
        self.bit: int | None = None  # the bit being checked; None: the reset (before part 0)
        self.confirming = False
        #: the address found; None until the scan ends with one
        self.found: tuple[int, int, int, int] | None = None
        #: why the scan ended without an address (None while running or after one is found)
        self.failed: str | None = None
        self.frames = 0

    @property
    def done(self) -> bool:
        return self.found is not None or self.failed is not None

    def next_frame(self) -> bytes | None:
        """The frame to send now; None when the scan is done."""
        if self.done:
            return None
        self.frames += 1
        if self.bit is None:
            return fast_scan_frame(0, FAST_SCAN_RESET, 0, 0)
        if self.confirming:
            return fast_scan_frame(self.ids[self.sub], 0, self.sub, (self.sub + 1) % 4)
        return fast_scan_frame(self.ids[self.sub], self.bit, self.sub, self.sub)

    def answered(self, yes: bool) -> None:
        """Whether any slave answered the last frame (4Fh within the caller's wait)."""
        if self.bit is None:  # the reset
            if not yes:
                self.failed = "no unconfigured LSS slave answered (none in LSS waiting without a node id)"
                return
            self._start_part()
        elif self.confirming:
            if not yes:
                self.failed = f"no slave confirmed the {PARTS[self.sub]} 0x{self.ids[self.sub]:08X} (it went away, or an answer came later than the wait)"  # fmt: skip
                return
            self.sub += 1
            if self.sub == 4:
                self.found = (self.ids[0], self.ids[1], self.ids[2], self.ids[3])
                return
            self._start_part()
        else:
            if not yes:  # nobody has a 0 there: the remaining slaves have a 1
                self.ids[self.sub] |= 1 << self.bit
            if self.bit == 0:
                self.confirming = True
            else:
                self.bit -= 1

    def _start_part(self) -> None:
        self.confirming = self.known[self.sub] is not None
        self.bit = 31
