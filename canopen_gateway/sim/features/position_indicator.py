"""Feature ``position_indicator``: set points in, status word out (AP05 manual 004, 4.1, 4.6,
5.3.1-5.3.3).

The PLC sends set points and the control word 5F0Ch by RPDO (RPDO1: set point1 5F16h:03,
RPDO2: set point2 5F16h:01; SDO writes of 5F16h/5F0Ch are refused as read-only, 5.7.2.34/42).
The device computes the status word 5F19h, sent in both TPDOs (bytes 6-7). This feature owns
these status bits (manual 5.3.3 Table 28):

  bit 0 / 1  arrow CW / CCW: a valid target exists and the position is outside target window1
             (5F10h); CW when the position must increase (6000h bit 0 = 0, "I" sense), the
             other arrow otherwise; 5F1Fh: 0 on, 1 inverted, 2 off (4.1.1.1)
  bit 2      set point1 valid   = control bit 2 (Table 27)
  bit 3      in target window2 (5F21h:01 > 0 and |position - target| <= window2)
  bit 4      target window1 static: latched on reaching window1, cleared by control bit 4
  bit 5      target window1 dynamic: |position - target| <= window1
  bit 6      deviation: position > target
  bit 10     set point2 valid   = control bit 9
  bit 7/11/12 battery empty / battery critical / sensor error (4.6, faults below)
  bit 13-15  keys (``press_key``)

The target is the last valid set point received (5.3.1.2: "the set point last received, if
valid, is output in the 2nd row"). Loop positioning (4.1.1.2, 5F14h length, 5F15h 1 loop+ /
2 loop-): a target approached from the wrong side is first overrun by the loop length. In the
alpha-numeric display mode (5F1Bh:02 = 3) bits 0, 1, 3-6 and 9 are left to the
``alphanumeric_display`` feature.

Faults (``SimNode.inject_fault``): ``battery_low`` (critical: status bit 11, 6503h bit 12,
6505h bit 4, EMCY FF20h), ``battery_empty`` (status bits 7 + 11, 6503h bit 13, EMCY 3200h,
1001h bit 7), ``sensor_error`` (status bit 12, 6503h bit 0, EMCY FF12h, 1001h bit 7), with
codes and bits from the profile's ``sim:`` hints battery_critical / battery_empty /
sensor_error (manual Tables 19-21 and 31; see the profile notes on 3200h vs FF20h).

On entering OPERATIONAL TPDO1 is sent once (the communication example 5.3.1.3 shows TPDO1 of
both devices right after "all operational", with the factory event timer 0).

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

OPERATIONAL = 0x05
ALPHANUMERIC_MODE = 3  # 5F1Bh:02 = 3 alpha-numeric display (5.7.2.45)

STATUS_CW = 0  # Table 28
STATUS_CCW = 1
STATUS_WINDOW2 = 3
STATUS_WINDOW1_STATIC = 4
STATUS_WINDOW1_DYNAMIC = 5
STATUS_DEVIATION = 6
CONTROL_ACK_WINDOW1 = 4  # Table 27: acknowledgement target window1 static

KEY_BITS = {"left": 13, "star": 14, "up": 15}  # Table 28 bits 13-15

_FAULT_DEFAULTS: dict[str, dict[str, Any]] = {
    # AP05 manual 4.6.1 Table 19 / 5.7.2.58-60 / Table 31
    "battery_critical": {"status_bit": 11, "emcy": 0xFF20, "alarm_bit": 12, "warning_bit": 4},
    # 4.6.2 Table 20: battery empty 3200h, status bits 11 + 7, 1001h bit 7
    "battery_empty": {
        "status_bits": [7, 11],
        "emcy": 0x3200,
        "alarm_bit": 13,
        "error_register_bit": 7,
    },
    # Table 20: admissible speed exceeded FF12h, status bit 12
    "sensor_error": {"status_bit": 12, "emcy": 0xFF12, "alarm_bit": 0, "error_register_bit": 7},
}
_FAULT_ALIASES = {"battery_low": "battery_critical"}


def _s32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v & 0x80000000 else v


def _obj(v: Any, default: str) -> ObjRef:
    return ObjRef.parse(v if v is not None else default)


@register
class PositionIndicator(SimFeature):
    feature = "position_indicator"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.status_obj = _obj(params.get("status_word"), "0x5F19:00")
        self.control_obj = _obj(params.get("control_word"), "0x5F0C:00")
        sp = params.get("set_points") or {1: "0x5F16:03", 2: "0x5F16:01"}
        self.set_point_objs = {int(k): ObjRef.parse(v) for k, v in sp.items()}
        rp = params.get("set_point_rpdo") or {1: 1, 2: 2}
        self.rpdo_to_set_point = {int(v): int(k) for k, v in rp.items()}
        cv = params.get("control_set_point_valid_bit") or {1: 2, 2: 9}
        self.control_valid_bit = {int(k): int(v) for k, v in cv.items()}
        sv = params.get("status_set_point_valid_bit") or {1: 2, 2: 10}
        self.status_valid_bit = {int(k): int(v) for k, v in sv.items()}
        self.window1_obj = _obj(params.get("target_window1"), "0x5F10:00")
        self.window2_obj = _obj(params.get("target_window2"), "0x5F21:01")
        self.mode_obj = _obj(params.get("operating_mode"), "0x5F1B:02")
        self.arrows_obj = _obj(params.get("direction_indicators"), "0x5F1F:00")
        self.loop_length_obj = _obj(params.get("loop_length"), "0x5F14:00")
        self.loop_type_obj = _obj(params.get("positioning_type"), "0x5F15:00")
        self.alarms_obj = _obj(params.get("alarms"), "0x6503:00")
        self.warnings_obj = _obj(params.get("warnings"), "0x6505:00")
        self.faults: dict[str, dict[str, Any]] = {}
        extra = node.hints.extra
        for name, default in _FAULT_DEFAULTS.items():
            self.faults[name] = {**default, **(extra.get(name) or {})}
        self.target: int | None = None
        self.target_source: int | None = None
        self.loop_via: int | None = None  # intermediate target of a loop approach
        self.window1_static = False
        self._was_in_window1 = False
        self.active_faults: set[str] = set()
        self.keys: set[str] = set()

    # -- helpers -----------------------------------------------------------------------------
    def _get(self, obj: ObjRef, default: int = 0) -> int:
        return int(self.node.get(*obj, default)) if self.node.values.has(*obj) else default

    def alphanumeric(self) -> bool:
        return self._get(self.mode_obj) == ALPHANUMERIC_MODE

    def position(self) -> int:
        pos_obj = self.node.hints.position
        return _s32(self._get(pos_obj)) if pos_obj is not None else 0

    # -- hooks -------------------------------------------------------------------------------
    def on_boot(self, now: float) -> None:
        if self.node.last_reset != "communication":
            self.target = None
            self.target_source = None
            self.loop_via = None
            self.window1_static = False
            self._was_in_window1 = False
        if self.node.last_reset == "power":
            self.active_faults.clear()
            self.keys.clear()
        for key in self.active_faults:  # reset node/comm reloaded the words: show them again
            self._fault_bits(self.faults[key], True)

    def on_nmt(self, state: int, now: float) -> None:
        if state == OPERATIONAL and self.node.tpdos:
            first = self.node.tpdos[0]
            if not self.node.get(0x1800 + first - 1, 5, 0):  # the timer sends it anyway
                self.node.trigger_tpdo(first, now)

    def on_rpdo(self, number: int, data: bytes, now: float) -> None:
        n = self.rpdo_to_set_point.get(number)
        if n is None:
            return
        control = self._get(self.control_obj)
        if control >> CONTROL_ACK_WINDOW1 & 1:
            self.window1_static = False
        if self.alphanumeric():
            return
        valid = bool(control >> self.control_valid_bit[n] & 1)
        if valid:
            target = _s32(self._get(self.set_point_objs[n]))
            if target != self.target:
                self._new_target(target)
            self.target_source = n
        elif self.target_source == n:
            self.target = None
            self.target_source = None
            self.loop_via = None

    def _new_target(self, target: int) -> None:
        self.target = target
        self.loop_via = None
        loop_type = self._get(self.loop_type_obj)
        loop = self._get(self.loop_length_obj)
        pos = self.position()
        # 4.1.1.2: loop+ approaches from below, loop- from above; overrun by the loop length
        if loop_type == 1 and target < pos:
            self.loop_via = target - loop
        elif loop_type == 2 and target > pos:
            self.loop_via = target + loop

    def update_process(self, now: float) -> None:
        status = self._get(self.status_obj)
        control = self._get(self.control_obj)
        for n, bit in self.status_valid_bit.items():
            valid = control >> self.control_valid_bit[n] & 1
            status = status | (1 << bit) if valid else status & ~(1 << bit)
        if not self.alphanumeric():
            status = self._positioning_bits(status)
        for name, bit in KEY_BITS.items():
            status = status | (1 << bit) if name in self.keys else status & ~(1 << bit)
        self.node.set(*self.status_obj, status & 0xFFFF)

    def _positioning_bits(self, status: int) -> int:
        owned = (
            1 << STATUS_CW
            | 1 << STATUS_CCW
            | 1 << STATUS_WINDOW2
            | 1 << STATUS_WINDOW1_STATIC
            | 1 << STATUS_WINDOW1_DYNAMIC
            | 1 << STATUS_DEVIATION
        )
        status &= ~owned
        if self.target is None:
            self._was_in_window1 = False
            return status
        pos = self.position()
        window1 = self._get(self.window1_obj)
        window2 = self._get(self.window2_obj)
        if self.loop_via is not None:
            reached = (
                pos <= self.loop_via + window1
                if self.loop_via < self.target
                else (pos >= self.loop_via - window1)
            )
            if reached:
                self.loop_via = None
        aim = self.loop_via if self.loop_via is not None else self.target
        in_window1 = self.loop_via is None and abs(pos - self.target) <= window1
        if in_window1:
            status |= 1 << STATUS_WINDOW1_DYNAMIC
            if not self._was_in_window1:
                self.window1_static = True
        self._was_in_window1 = in_window1
        if self.window1_static:
            status |= 1 << STATUS_WINDOW1_STATIC
        if window2 > 0 and abs(pos - self.target) <= window2:
            status |= 1 << STATUS_WINDOW2
        if pos > self.target:
            status |= 1 << STATUS_DEVIATION
        if not in_window1:
            arrows = self._get(self.arrows_obj)
            increase = aim > pos
            if self.node.direction_sign() < 0:
                increase = not increase
            cw = increase if arrows == 0 else not increase
            if arrows != 2:
                status |= 1 << (STATUS_CW if cw else STATUS_CCW)
        return status

    # -- faults and keys ---------------------------------------------------------------------
    def on_fault(self, name: str, active: bool, now: float) -> bool:
        key = _FAULT_ALIASES.get(name, name)
        spec = self.faults.get(key)
        if spec is None:
            return False
        if active == (key in self.active_faults):
            return True
        if active:
            self.active_faults.add(key)
        else:
            self.active_faults.discard(key)
        self._fault_bits(spec, active)
        code = spec.get("emcy")
        if code is not None:
            register = 1 << int(spec["error_register_bit"]) if "error_register_bit" in spec else 0
            if active:
                self.node.raise_emcy(int(code), register, now=now)
            else:
                self.node.clear_emcy(int(code), now=now)
        return True

    def _fault_bits(self, spec: dict[str, Any], active: bool) -> None:
        """Status word, 6503h alarm and 6505h warning bits of one fault."""
        bits = list(spec.get("status_bits") or [spec["status_bit"]])
        status = self._get(self.status_obj)
        for b in bits:
            # a bit shared by two faults (11: critical and empty) stays while either is active
            keep = any(
                b in (self.faults[f].get("status_bits") or [self.faults[f].get("status_bit")])
                for f in self.active_faults
            )
            status = status | (1 << b) if active or keep else status & ~(1 << b)
        self.node.set(*self.status_obj, status)
        self._set_bit(self.alarms_obj, spec.get("alarm_bit"), active)
        self._set_bit(self.warnings_obj, spec.get("warning_bit"), active)

    def _set_bit(self, obj: ObjRef, bit: Any, on: bool) -> None:
        if bit is None or not self.node.values.has(*obj):
            return
        v = self._get(obj)
        self.node.set(*obj, v | (1 << int(bit)) if on else v & ~(1 << int(bit)))

    def press_key(self, name: str, pressed: bool = True) -> None:
        """Hold a key down (status bits 13-15) or release it."""
        if name not in KEY_BITS:
            raise ValueError(f"unknown key {name!r}; keys: {sorted(KEY_BITS)}")
        if pressed:
            self.keys.add(name)
        else:
            self.keys.discard(name)
        self.node.invalidate_process()
