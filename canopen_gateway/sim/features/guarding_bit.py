"""Feature ``guarding_bit``: control word bit echoed in the status word (AP05 manual 5.5.5).

"When receiving the control word, the content of this bit will be copied into the guarding bit
of the status word and output with the next TPDO." Control word 5F0Ch bit 8 (Table 27) ->
status word 5F19h bit 8 (Table 28), on every RPDO that carries the control word. The fault
``freeze_guarding_echo`` stops the copying (the status bit keeps its last value), which is how
a gateway's guarding-bit check is tested.

Parameters (profile ``features: guarding_bit:``): control, control_bit, status, status_bit.

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features, canopen_gateway.sim.pdo.
"""

from __future__ import annotations

from typing import Any

import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register


@register
class GuardingBit(SimFeature):
    feature = "guarding_bit"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.control_obj = ObjRef.parse(params.get("control", "0x5F0C:00"))
        self.control_bit = int(params.get("control_bit", 8))
        self.status_obj = ObjRef.parse(params.get("status", "0x5F19:00"))
        self.status_bit = int(params.get("status_bit", 8))
        self.frozen = False
        self.echo = 0
        self.echoes = 0

    def on_boot(self, now: float) -> None:
        if self.node.last_reset == "power":
            self.echo = 0
            self.frozen = False

    def on_rpdo(self, number: int, data: bytes, now: float) -> None:
        if self.frozen:
            return
        mapped = {ObjRef(e.index, e.sub) for e in pdo.mapping(self.node.values, "rpdo", number)}
        if self.control_obj not in mapped:
            return
        self.echo = int(self.node.get(*self.control_obj, 0)) >> self.control_bit & 1
        self.echoes += 1
        self.node.invalidate_process()

    def update_process(self, now: float) -> None:
        status = int(self.node.get(*self.status_obj, 0))
        mask = 1 << self.status_bit
        status = status | mask if self.echo else status & ~mask
        self.node.set(*self.status_obj, status)

    def on_fault(self, name: str, active: bool, now: float) -> bool:
        if name != "freeze_guarding_echo":
            return False
        self.frozen = active
        return True
