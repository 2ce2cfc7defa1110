"""Setting ``verify_mapping``: after configuring, read the PDO mapping objects back and compare
them with the layout the codecs decode (``pdo.verify``); until they match, the node's PDO
signals are not served (flagged invalid), and a mismatch says where.

Imports: bus.node.features, bus.events, pdo.verify, canopen.objref;
bus.sdo.channel and bus.sdo.client for types only. No I/O.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from canopen_gateway.bus.events import HealthChanged, Note, Output
from canopen_gateway.bus.node.features import NodeContext, NodeFeature
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.pdo.verify import MappingMismatch, MappingRead, compare_mapping

if TYPE_CHECKING:
    from canopen_gateway.bus.sdo.channel import SdoJob
    from canopen_gateway.bus.sdo.client import SdoTransfer


class VerifyMapping(NodeFeature):
    purposes = ("verify",)

    def __init__(
        self,
        reads: Sequence[MappingRead],
        pdo_names: frozenset[str],
        still_invalid: Callable[[frozenset[str]], set[str]] = lambda invalid: set(),
    ):
        self.reads = list(reads)
        self.pdo_names = pdo_names
        #: of the signals flagged invalid, those another feature keeps invalid (referencing)
        self.still_invalid = still_invalid
        self.held: dict[ObjRef, int | None] = {}
        self.mismatches: list[MappingMismatch] = []

    def on_bootup(self, node: NodeContext, now: float) -> list[Output]:
        # not trusted until the mapping is read back and compared
        node.health.invalid_signals = node.health.invalid_signals | self.pdo_names
        return []

    def on_configured(self, node: NodeContext, now: float) -> list[Output]:
        self.held = {}
        for r in self.reads:
            node.sdo.queue(r.object, None, "verify", now, r)
        return []

    def on_adopted(self, node: NodeContext, now: float) -> list[Output]:
        # a standby cannot read the mapping back; read it now if it is still not trusted
        if node.health.invalid_signals & self.pdo_names:
            return self.on_configured(node, now)
        return []

    def sdo_done(self, node: NodeContext, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        """Collect the uploads; when all are in, compare."""
        r: MappingRead = job.arg
        raw = tr.result
        self.held[r.object] = int.from_bytes(raw[:4], "little") if raw else None
        if len(self.held) < len(self.reads):
            return []
        h = node.health
        self.mismatches = compare_mapping(self.reads, self.held)
        if self.mismatches:
            text = "; ".join(str(m) for m in self.mismatches)
            h.last_error = f"PDO mapping mismatch, values not served: {text}"
            h.invalid_signals = h.invalid_signals | self.pdo_names
            note = Note(logging.ERROR, f"node {node.name}: {h.last_error}")
        else:
            keep = self.still_invalid(h.invalid_signals)
            h.invalid_signals = (h.invalid_signals - self.pdo_names) | keep
            note = Note(logging.INFO, f"node {node.name}: PDO mapping verified ({len(self.reads)} objects read back)")  # fmt: skip
        return [note, HealthChanged("state")]
