"""A node whose values come only in SYNC-driven TPDOs (transmission type 0..240, CiA 301
7.5.2.35) while no SYNC producer is configured (``master.sync_period_ms`` 0, no
``master.sync_external``): the device never sends them, so those values stay bad. At NMT
start the node's ``last_error`` says so ("waiting for SYNC-driven TPDOs: no SYNC producer")
with a log line; when such a TPDO arrives after all (another master's SYNC), the text is taken
back at the node's next tick (a steady heartbeat-supervised node ticks at its consumer deadline).

Imports: bus.node.features, bus.events, pdo.codec (types), logging. No I/O.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from canopen_gateway.bus.events import HealthChanged, Note, Output
from canopen_gateway.bus.node.features import NodeContext, NodeFeature
from canopen_gateway.pdo.codec import TpdoCodec

#: the start of the node's ``last_error`` while it waits (docs/canopen.md, SYNC producer)
WAITING = "waiting for SYNC-driven TPDOs: no SYNC producer"


class SyncWait(NodeFeature):
    """``waiting``: the SYNC-driven TPDOs that alone carry some of the node's signals."""

    def __init__(self, waiting: Sequence[TpdoCodec]):
        self.waiting = list(waiting)
        pdos = ", ".join(f"TPDO{c.number}" for c in self.waiting)
        names = sorted({n for c in self.waiting for n in c.names})
        verb = "carries" if len(self.waiting) == 1 else "carry"
        self.text = (
            f"{WAITING} ({pdos} {verb} {', '.join(names)}; master.sync_period_ms is 0 and "
            "master.sync_external is not set)"
        )

    @staticmethod
    def of(tpdos: Sequence[TpdoCodec], sync_numbers: Sequence[int], other_names: set[str]) -> SyncWait | None:
        """The feature for a node whose TPDOs ``sync_numbers`` are SYNC-driven, or None when
        every signal they carry also comes another way (another TPDO, ``other_names``)."""
        sync = [c for c in tpdos if c.number in sync_numbers]
        others = set(other_names) | {n for c in tpdos if c.number not in sync_numbers for n in c.names}
        alone = [c for c in sync if set(c.names) - others]
        return SyncWait(alone) if alone else None

    def on_configured(self, node: NodeContext, now: float) -> list[Output]:
        node.health.last_error = self.text
        return [Note(logging.WARNING, f"node {node.name}: {self.text}"), HealthChanged("state")]

    def tick(self, node: NodeContext, now: float) -> list[Output]:
        h = node.health
        if h.last_error != self.text or node.image is None or h.fresh_since is None:
            return []
        records = node.image.records
        for c in self.waiting:
            r = records.get(c.names)
            if r is not None and r[2] >= h.fresh_since:
                h.last_error = ""
                note = f"node {node.name}: TPDO{c.number} arrives: another master sends SYNC (say so with master.sync_external: true)"  # fmt: skip
                return [Note(logging.INFO, note), HealthChanged("state")]
        return []
