"""Feature ``referencing`` (MSK5000 manual 5115h): the position is not valid until the device is
referenced, and the reference is lost at power-on. The gateway reads the referencing state
after configuration, after an EMCY and after a client writes the referencing command, and
flags the position signal invalid (quality ``bad``) while it is not referenced.

Imports: objref, image (the node's health it marks). No I/O.
"""

from __future__ import annotations

from typing import Any

from gateway.image import NodeHealth
from gateway.objref import ObjRef


class Referencing:
    def __init__(self, spec: dict[str, Any], signal: str | None):
        self.status = ObjRef.parse(spec["status"])
        self.command = ObjRef.parse(spec["command"])
        self.referenced_value = int(spec.get("referenced_value", 1))
        self.signal = signal

    def is_command(self, obj: ObjRef, data: bytes | None) -> bool:
        """A client's SDO download of the referencing command."""
        return data is not None and obj == self.command

    def referenced(self, status: bytes) -> bool:
        """The referencing state read from the status object."""
        return int.from_bytes(status[:1], "little") == self.referenced_value

    def apply(self, health: NodeHealth, ok: bool) -> str | None:
        """Mark the signal valid or not; the log line when that changed (None: no change)."""
        sig = self.signal
        if sig is None or (sig not in health.invalid_signals) == ok:
            return None
        if ok:
            health.invalid_signals = health.invalid_signals - {sig}
            return f"referenced; {sig} valid"
        health.invalid_signals = health.invalid_signals | {sig}
        return f"not referenced; {sig} is not valid"
