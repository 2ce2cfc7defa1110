"""Feature ``referencing`` (MSK5000 manual 5115h): the position is not valid until the device is
referenced, and the reference is lost at power-on. The gateway reads the referencing state
after configuration, after an EMCY and after a client writes the referencing command, and
flags the position signal invalid (quality ``bad``) while it is not referenced.

Imports: bus.node.features, bus.events, canopen.objref, image (the node's health it marks);
bus.sdo.channel and bus.sdo.client for types only. No I/O.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from canopen_gateway.bus.events import HealthChanged, Note, Output
from canopen_gateway.bus.node.features import NodeContext, NodeFeature
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.image import NodeHealth

if TYPE_CHECKING:
    from canopen_gateway.bus.sdo.channel import SdoJob
    from canopen_gateway.bus.sdo.client import SdoTransfer


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


class ReferencingFeature(NodeFeature):
    """The node's hooks of feature ``referencing`` (see the module docstring)."""

    purposes = ("reference",)

    def __init__(self, spec: dict[str, Any], signal: str | None):
        self.ref = Referencing(spec, signal)

    def on_bootup(self, node: NodeContext, now: float) -> list[Output]:
        return self._set(node, False)  # MSK5000 5115h: the reference is lost at power-on

    def on_configured(self, node: NodeContext, now: float) -> list[Output]:
        self._check(node, now)
        return []

    def on_emcy(self, node: NodeContext, now: float) -> bool:
        self._check(node, now)
        return True

    def on_user_sdo(self, node: NodeContext, job: SdoJob, now: float) -> list[Output]:
        if self.ref.is_command(job.obj, job.data):
            self._check(node, now)
        return []

    def sdo_done(self, node: NodeContext, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        if tr.result is None:
            note = f"node {node.name}: referencing state unreadable (0x{tr.abort_code or 0:08X})"
            return [Note(logging.WARNING, note), *self._set(node, False)]
        return self._set(node, self.ref.referenced(tr.result))

    def still_invalid(self, invalid: frozenset[str]) -> set[str]:
        """The position signal stays invalid while not referenced (for ``verify_mapping``)."""
        sig = self.ref.signal
        return {sig} & invalid if sig is not None else set()

    def _check(self, node: NodeContext, now: float) -> None:
        """Read whether the position is referenced."""
        node.sdo.queue(self.ref.status, None, "reference", now)

    def _set(self, node: NodeContext, ok: bool) -> list[Output]:
        text = self.ref.apply(node.health, ok)
        if text is None:
            return []
        level = logging.INFO if ok else logging.WARNING
        return [Note(level, f"node {node.name}: {text}"), HealthChanged("state")]
