"""Setting ``rtr_poll_ms``: ask every TPDO by RTR at that period while the node is operational
(for devices whose TPDOs are sent only on request).

Imports: bus.node.features, bus.events, pdo.codec, canopen.states. No I/O.
"""

from __future__ import annotations

from collections.abc import Sequence

from canopen_gateway.bus.events import Output, Send
from canopen_gateway.bus.node.features import NodeContext, NodeFeature
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.pdo.codec import TpdoCodec


class RtrPoll(NodeFeature):
    def __init__(self, period_ms: int, tpdos: Sequence[TpdoCodec]):
        self.period_s = period_ms / 1000.0
        self.tpdos = list(tpdos)
        self.due_s: float | None = None

    def on_invalidate(self, node: NodeContext) -> None:
        self.due_s = None

    def on_configured(self, node: NodeContext, now: float) -> list[Output]:
        self.due_s = now + self.period_s
        return []

    def next_deadline(self) -> float | None:
        return self.due_s

    def tick(self, node: NodeContext, now: float) -> list[Output]:
        if self.due_s is None or now < self.due_s:
            return []
        self.due_s = now + self.period_s
        if node.health.nmt_state != NmtState.OPERATIONAL:
            return []
        return [Send(c.cob_id, b"", rtr=True, dlc=c.length) for c in self.tpdos]
