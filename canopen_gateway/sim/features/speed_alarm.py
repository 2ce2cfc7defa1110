"""Overspeed alarm with a settable threshold (MSK5000CAN manual 4.6.1.26, object 5FFAh).

What the manual says: 5FFAh (SIGNED 16) is the maximum speed in mm/s, 0 = alarm off; allowed
50..32767 at 5 um resolution and 100..32767 at 10 um (6005h:01 = 5000 / 10000 nm); "only active
in Operational Mode". It does not say how the alarm shows, so (profile notes) the alarm is EMCY
FF12h "Speed error" (Table 9) with error register bit 7 (manufacturer) while |speed| exceeds the
threshold in OPERATIONAL, cleared with EMCY 0000h when the speed is back at or below it or the
node leaves OPERATIONAL. The speed is 6030h:01 in units of 6005h:02 x 0.01 mm/s.

Also kept here: 5122h:01 bit 2 "Speed check (v > 5 m/s)" (4.6.1.23), the fixed hardware limit
(profile sim hint ``hardware_speed_limit_mm_s``).

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

_OPERATIONAL = 0x05  # NMT state byte (manual 4.5.3)
_ABORT_RANGE = 0x06090030  # manual 4.4.1.3 Table 8
_EMCY_SPEED = 0xFF12  # manual 4.5.1 Table 9 "Manufacturer specific: Speed error"
_REGISTER_ENCODER = 0x80  # 1001h bit 7 manufacturer-specific (encoder error), 4.6.1.2
_SPEED_CHECK_BIT = 2  # 5122h:01 bit 2 speed check v > 5 m/s (4.6.1.23)
_HW_LIMIT_HINT = "hardware_speed_limit_mm_s"  # profile ``sim:`` hint of that fixed limit


def _obj(params: dict[str, Any], key: str, default: str) -> ObjRef:
    return ObjRef.parse(params.get(key, default))


@register
class SpeedAlarm(SimFeature):
    """5FFAh threshold check on 6030h:01 in OPERATIONAL; EMCY FF12h on / 0000h off."""

    feature = "speed_alarm"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.threshold = _obj(params, "threshold", "0x5FFA:00")
        self.speed = _obj(params, "speed", "0x6030:01")
        self.resolution = _obj(params, "resolution", "0x6005:01")
        self.increment = _obj(params, "speed_unit_0_01mm_s", "0x6005:02")
        self.off_value = int(params.get("off_value", 0))
        self.range_5um = tuple(params.get("range_5um", (50, 32767)))
        self.range_10um = tuple(params.get("range_10um", (100, 32767)))
        self.emcy_code = int(params.get("emcy_code", _EMCY_SPEED))
        bits = params.get("error_register_bits", [0, 7])
        self.register = sum(1 << int(b) for b in bits) & ~0x01 or _REGISTER_ENCODER
        self.abort_range = int(params.get("abort_out_of_range", _ABORT_RANGE))
        limit = params.get("hardware_speed_limit_mm_s", node.hints.extra.get(_HW_LIMIT_HINT))
        self.hardware_limit_mm_s = float(limit) if limit is not None else None
        self.sys_register = ObjRef.parse(params.get("sys_register", "0x5122:01"))
        self.active = False
        self.alarms = 0  # how many times the alarm went on (for tests, demos)

    # -- values ------------------------------------------------------------------------------
    def speed_mm_s(self) -> float:
        """6030h:01 in mm/s (x 6005h:02 x 0.01 mm/s)."""
        raw = int(self.node.get(self.speed.index, self.speed.sub, 0) or 0)
        step = int(self.node.get(self.increment.index, self.increment.sub, 100) or 100)
        return raw * step * 0.01

    def allowed_range(self) -> tuple[int, int]:
        """The 5FFAh range of the resolution set in 6005h:01 (5000 nm = 5 um)."""
        nm = int(self.node.get(self.resolution.index, self.resolution.sub, 5000) or 5000)
        lo, hi = self.range_10um if nm >= 10000 else self.range_5um
        return int(lo), int(hi)

    # -- hooks -------------------------------------------------------------------------------
    def before_sdo_write(self, obj: ObjRef, value: Any, now: float) -> int | None:
        if obj != self.threshold:
            return None
        v = int(value)
        if v == self.off_value:
            return None
        lo, hi = self.allowed_range()
        return None if lo <= v <= hi else self.abort_range

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        if obj == self.threshold:
            self._evaluate(now)

    def on_boot(self, now: float) -> None:
        self.active = False

    def on_nmt(self, state: int, now: float) -> None:
        if state != _OPERATIONAL:
            self._set_alarm(False, now)

    def tick(self, now: float) -> None:
        """Watch the speed without waiting for a TPDO or SDO read."""
        if int(self.node.nmt_state) == _OPERATIONAL or self.hardware_limit_mm_s is not None:
            self.node.update_process(now)  # calls update_process below once per ``now``

    def update_process(self, now: float) -> None:
        self._evaluate(now)

    # -- the alarm ---------------------------------------------------------------------------
    def _evaluate(self, now: float) -> None:
        speed = abs(self.speed_mm_s())
        if self.hardware_limit_mm_s is not None and self.node.values.has(*self.sys_register):
            value = int(self.node.get(*self.sys_register, 0) or 0)
            bit = 1 << _SPEED_CHECK_BIT
            new = value | bit if speed > self.hardware_limit_mm_s else value & ~bit
            if new != value:
                self.node.set(self.sys_register.index, self.sys_register.sub, new)
        threshold = int(self.node.get(self.threshold.index, self.threshold.sub, 0) or 0)
        on = (
            int(self.node.nmt_state) == _OPERATIONAL
            and threshold != self.off_value
            and speed > threshold
        )
        self._set_alarm(on, now)

    def _set_alarm(self, on: bool, now: float) -> None:
        if on == self.active:
            return
        self.active = on
        if on:
            self.alarms += 1
            self.node.raise_emcy(self.emcy_code, self.register, now=now)
        else:
            self.node.clear_emcy(self.emcy_code, now=now)
