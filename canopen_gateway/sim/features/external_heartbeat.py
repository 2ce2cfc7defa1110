"""Feature ``external_heartbeat``: RPDO or SYNC watchdog (AP05 manual 5.5.4, 5.7.2.31 5F09h).

"If the device receives no external heartbeat message during this interval, the display will
switch over to Pre-Operational status." 5F09h:01 is the interval in ms (0 = off), 5F09h:02 the
source: 0 any RPDO (set point), 1 a SYNC. The watch runs while the node is OPERATIONAL; it
starts when OPERATIONAL is entered or the interval is written. At exactly ``interval`` after the
last event the node is still OPERATIONAL; later it drops to PRE-OPERATIONAL (no boot-up, no
reset). Only a later NMT start brings it back.

Parameters (profile ``features: external_heartbeat:``): interval, source (objects), sources
(value -> "rpdo" / "sync").

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F
_EPS_S = 1e-9


@register
class ExternalHeartbeat(SimFeature):
    feature = "external_heartbeat"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.interval_obj = ObjRef.parse(params.get("interval", "0x5F09:01"))
        self.source_obj = ObjRef.parse(params.get("source", "0x5F09:02"))
        sources = params.get("sources") or {0: "rpdo", 1: "sync"}
        self.sources = {int(k): str(v) for k, v in sources.items()}
        self.last_event_s: float | None = None
        self.timeouts = 0

    def source(self) -> str:
        return self.sources.get(int(self.node.get(*self.source_obj, 0)), "rpdo")

    def interval_s(self) -> float:
        return int(self.node.get(*self.interval_obj, 0)) / 1000

    def on_nmt(self, state: int, now: float) -> None:
        self.last_event_s = now if state == OPERATIONAL else None

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        if obj in (self.interval_obj, self.source_obj) and self.last_event_s is not None:
            self.last_event_s = now

    def on_rpdo(self, number: int, data: bytes, now: float) -> None:
        if self.source() == "rpdo" and self.last_event_s is not None:
            self.last_event_s = now

    def on_sync(self, now: float) -> None:
        if self.source() == "sync" and self.last_event_s is not None:
            self.last_event_s = now

    def tick(self, now: float) -> None:
        interval_s = self.interval_s()
        if self.last_event_s is None or interval_s <= 0:
            return
        if self.node.nmt_state != OPERATIONAL:
            self.last_event_s = None
            return
        if now - self.last_event_s > interval_s + _EPS_S:
            self.timeouts += 1
            self.last_event_s = None
            self.node.set_nmt_state(PRE_OPERATIONAL, now)
