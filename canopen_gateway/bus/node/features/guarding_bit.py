"""Feature ``guarding_bit`` (AP05 manual 5.5.5, 5.3.2, 5.3.3): the process-data link check. The
gateway toggles a bit of the control word in every RPDO (``bus.node.outputs`` asks the check
for it) and the device echoes it in the status word of its TPDO; the link is OK while the
echoes follow, FAULT after the tolerance (missed status words or time), UNKNOWN after a boot-up
or a loss until the next echo. The node's health says it (``NodeHealth.link``).

Imports: bus.node.features, bus.events, bus.error_control.guarding_bit, canopen.states. No I/O.
"""

from __future__ import annotations

import logging

from canopen_gateway.bus.error_control.guarding_bit import GuardingBitCheck, LinkFault, LinkOk
from canopen_gateway.bus.events import HealthChanged, Note, Output
from canopen_gateway.bus.node.features import NodeContext, NodeFeature
from canopen_gateway.canopen.states import LinkState


class GuardingBitLink(NodeFeature):
    def __init__(self, check: GuardingBitCheck):
        self.check = check

    def on_bootup(self, node: NodeContext, now: float) -> list[Output]:
        self.check.reset()
        return self._set(node, LinkState.UNKNOWN)

    def on_lost(self, node: NodeContext) -> list[Output]:
        self.check.reset()
        return self._set(node, LinkState.UNKNOWN)

    def on_echo(self, node: NodeContext, bit: int, now: float) -> list[Output]:
        """The guarding bit of a status word just received in a TPDO."""
        return self._changes(node, self.check.on_status(bit, now))

    def next_deadline(self) -> float | None:
        return self.check.next_deadline()

    def tick(self, node: NodeContext, now: float) -> list[Output]:
        return self._changes(node, self.check.poll(now))

    def _changes(self, node: NodeContext, changes: list[LinkOk | LinkFault]) -> list[Output]:
        out: list[Output] = []
        for ch in changes:
            out += self._set(node, LinkState.OK if isinstance(ch, LinkOk) else LinkState.FAULT)
        return out

    def _set(self, node: NodeContext, state: LinkState) -> list[Output]:
        h = node.health
        if h.link == state:
            return []
        out: list[Output] = []
        if state == LinkState.FAULT:
            h.link_fault_count += 1
            out.append(
                Note(
                    logging.WARNING,
                    f"node {node.name}: guarding-bit link FAULT (process data not echoed)",
                )
            )
        elif h.link == LinkState.FAULT:
            out.append(Note(logging.INFO, f"node {node.name}: guarding-bit link restored"))
        h.link = state
        out.append(HealthChanged("state"))
        return out
