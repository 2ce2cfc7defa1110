"""Setting ``rtr_poll_ms``: ask every TPDO by RTR at that period while the node is operational
(for devices whose TPDOs are sent only on request).

Imports: bus.node.features, bus.node.events, pdo.codec, states; bus.node.node for types only.
No I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from gateway.bus.node.events import Output, Send
from gateway.bus.node.features import NodeFeature
from gateway.pdo.codec import TpdoCodec
from gateway.states import NmtState

if TYPE_CHECKING:
    from gateway.bus.node.node import Node


class RtrPoll(NodeFeature):
    def __init__(self, period_ms: int, tpdos: Sequence[TpdoCodec]):
        self.period_s = period_ms / 1000.0
        self.tpdos = list(tpdos)
        self.due_s: float | None = None

    def on_invalidate(self, node: Node) -> None:
        self.due_s = None

    def on_configured(self, node: Node, now: float) -> list[Output]:
        self.due_s = now + self.period_s
        return []

    def next_deadline(self) -> float | None:
        return self.due_s

    def tick(self, node: Node, now: float) -> list[Output]:
        if self.due_s is None or now < self.due_s:
            return []
        self.due_s = now + self.period_s
        if node.health.nmt_state != NmtState.OPERATIONAL:
            return []
        return [Send(c.cob_id, b"", rtr=True, dlc=c.length) for c in self.tpdos]
