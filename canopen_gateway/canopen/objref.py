"""CANopen object addresses written as ``0x6004:00``.

Knows only how to parse and format an (index, sub-index) pair. Imports nothing from the gateway.

Imports: nothing of the gateway.
"""

from __future__ import annotations

import re
from typing import NamedTuple

_OBJ_RE = re.compile(r"^\s*(?:0x)?([0-9A-Fa-f]{1,4})h?\s*(?::\s*(?:0x)?([0-9A-Fa-f]{1,2})h?)?\s*$")


class ObjRef(NamedTuple):
    """An object dictionary entry: 16-bit index and 8-bit sub-index."""

    index: int
    sub: int

    def __str__(self) -> str:
        return f"0x{self.index:04X}:{self.sub:02X}"

    @classmethod
    def parse(cls, text: str | int | ObjRef) -> ObjRef:
        """Parse ``0x6004:00``, ``6004:0``, ``6004h:00h`` or ``0x6004`` (sub-index 0)."""
        if isinstance(text, ObjRef):
            return text
        if isinstance(text, int):
            return cls(text, 0)
        m = _OBJ_RE.match(str(text))
        if not m:
            raise ValueError(f"not an object address {text!r} (expected like 0x6004:00)")
        return cls(int(m.group(1), 16), int(m.group(2) or "0", 16))
