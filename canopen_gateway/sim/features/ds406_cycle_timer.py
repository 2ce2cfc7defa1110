"""Feature ``ds406_cycle_timer``: the DS-406 cyclic timer 6200h is the event timer 1800h:05.

SGH10 manual 4.7.2.31 (and MSK5000 4.6.1): writing either object changes both. Only devices
whose profile names the feature get this coupling: on a CiA 401 I/O module 6200h is a digital
output and must stay independent of the TPDO1 event timer.

Imports: canopen_gateway.canopen.objref, the feature base class (sim.features), sim.node (types).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

if TYPE_CHECKING:
    from canopen_gateway.sim.node import SimNode

EVENT_TIMER_TPDO1 = ObjRef(0x1800, 0x05)  # DS-301 180xh:05
CYCLIC_TIMER = ObjRef(0x6200, 0x00)  # DS-406 6200h, SGH10 manual 4.7.2.31


@register
class Ds406CycleTimer(SimFeature):
    feature = "ds406_cycle_timer"

    def __init__(self, node: SimNode, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        group = (EVENT_TIMER_TPDO1, CYCLIC_TIMER)
        present = tuple(o for o in group if node.values.has(*o))
        if len(present) == 2 and not any(set(group) <= set(g) for g in node.mirror_groups):
            node.mirror_groups.append(present)
