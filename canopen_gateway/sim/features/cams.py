"""Feature ``cams``: DS-406 cam states computed from the position (BEI POSI+ manual 002, 6300h-6320h).

One cam per channel ("Only one CAM is available", manual 002 "Encoder Cam1"). The device
computes the cam state only while bit 0 of the cam enable 6301h:01 is 1. The cam is active
while the position 6004h lies between the low limit 6310h:01 and the high limit 6320h:01, both
included. With the polarity bit 6302h:01 = 1 an active cam reads 0 and an inactive one 1
(manual 002 cam chapter; the overview's "1 = cam state not inverted" is a misprint). The
state is written to bit 0 of 6300h:01 before every TPDO and every SDO read.

Choices where the manual is silent, after DS-406: a disabled cam reads 0 whatever its polarity;
a low limit above the high limit makes a cam that wraps through the end of the measuring range
(active when position >= low or position <= high).

Imports: canopen_gateway.sim.features, canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register


def cam_active(position: int, low: int, high: int) -> bool:
    """DS-406 cam: low <= position <= high; a wrapping cam when low > high."""
    if low <= high:
        return low <= position <= high
    return position >= low or position <= high


@register
class Cams(SimFeature):
    feature = "cams"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.state = ObjRef.parse(params.get("state", "0x6300:01"))
        self.enable = ObjRef.parse(params.get("enable", "0x6301:01"))
        self.polarity = ObjRef.parse(params.get("polarity", "0x6302:01"))
        self.low_limit = ObjRef.parse(params.get("low_limit", "0x6310:01"))
        self.high_limit = ObjRef.parse(params.get("high_limit", "0x6320:01"))
        self.position = ObjRef.parse(params.get("position", "0x6004:00"))

    def compute(self) -> int:
        """The cam state register value (bit 0 = cam 1) for the current objects."""
        if not int(self.node.get(*self.enable, 0)) & 1:
            return 0
        active = cam_active(
            int(self.node.get(*self.position, 0)),
            int(self.node.get(*self.low_limit, 0)),
            int(self.node.get(*self.high_limit, 0)),
        )
        inverted = bool(int(self.node.get(*self.polarity, 0)) & 1)
        return int(active != inverted)

    def update_process(self, now: float) -> None:
        value = self.compute()
        if self.node.get(*self.state) != value:
            self.node.set(*self.state, value)

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        if obj in (self.enable, self.polarity, self.low_limit, self.high_limit):
            self.node.set(*self.state, self.compute())
