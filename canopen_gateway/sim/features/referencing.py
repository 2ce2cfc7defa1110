"""Referencing of an incremental encoder: no valid position until referenced (MSK5000CAN 5115h).

What the manual says (MSK5000CAN manual 3 NOTICE, 3.2, 4.6.1.22, 4.6.1.29, 4.6.1.38):

- after switching on, the encoder "must be referenced; otherwise, the encoder does not provide
  any position values": 5115h reads 0, the position value 6004h is 0 (2: "a position value of
  0 is output" on a read error), the sys register 5122h:01 bit 1 "Encoder not referenced" is
  set, and an SDO read of 6004h is refused with 08000024h "No data available" (Table 8; the
  profile's ``unreferenced_sdo_abort``);
- writing 1 to 5115h "sets the position value to the calibration value" 6003h: from then on
  position value = measurement value + (6003h - measurement at referencing); 6509h holds the
  measurement at referencing; 5115h reads 1;
- the reference is lost at power-on and reset node, and "due to a sensor error" (fault
  ``sensor_error``: 5122h:01 bit 0 "read distance error", EMCY FF10h "Tape encoder", position
  0). A reset of communication keeps it.

Object addresses come from the feature parameters (``command``, ``calibration``, ``offset``,
``position``, ``not_referenced_flag``...), with the MSK5000CAN objects as defaults.

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

# MSK5000CAN manual 4.4.1.3 Table 8: 08000024h "No data available"
_ABORT_NO_DATA = 0x08000024
# Table 8: 06090030h "Value range of the selected parameter incorrect"
_ABORT_RANGE = 0x06090030
# Table 9: FF10h "Manufacturer specific: Tape encoder"; 1001h bit 7 manufacturer (encoder) error
_EMCY_TAPE = 0xFF10
_REGISTER_ENCODER = 0x80
# 5122h:01 bit 0 "Encoder/tape read distance error" (4.6.1.23)
_SYS_READ_DISTANCE_BIT = 0


def _obj(params: dict[str, Any], key: str, default: str) -> ObjRef:
    return ObjRef.parse(params.get(key, default))


@register
class Referencing(SimFeature):
    """5115h referencing: position only after the command, lost on power-on or sensor error."""

    feature = "referencing"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.command = _obj(params, "command", "0x5115:00")
        self.status = _obj(params, "status", str(self.command))
        self.command_value = int(params.get("command_value", 1))
        self.referenced_value = int(params.get("referenced_value", 1))
        self.calibration = _obj(params, "calibration", "0x6003:00")
        self.offset = _obj(params, "offset", "0x6509:00")
        self.position = _obj(params, "position", "0x6004:00")
        flag = params.get("not_referenced_flag") or {"object": "0x5122:01", "bit": 1}
        self.flag_obj = ObjRef.parse(flag["object"])
        self.flag_bit = int(flag["bit"])
        self.unreferenced_position = int(params.get("unreferenced_position_value", 0))
        self.unreferenced_abort = int(params.get("unreferenced_sdo_abort", _ABORT_NO_DATA))
        self.referenced = False
        self.sensor_error = False
        self.references = 0  # how many times the encoder was referenced (for tests, demos)

    # -- state -------------------------------------------------------------------------------
    def _measurement(self, now: float) -> int:
        """Counts of the measuring system now (the motion model, without any offset)."""
        pos, _ = self.node.motion.sample(now)
        return int(round(pos))

    def _set_bit(self, obj: ObjRef, bit: int, on: bool) -> None:
        value = int(self.node.get(obj.index, obj.sub, 0) or 0)
        value = value | (1 << bit) if on else value & ~(1 << bit)
        self.node.set(obj.index, obj.sub, value)

    def _lose_reference(self) -> None:
        self.referenced = False
        self.node.set_position_offset(0)
        self.node.set(self.status.index, self.status.sub, 0)
        self._set_bit(self.flag_obj, self.flag_bit, True)
        self.node.set(self.position.index, self.position.sub, self.unreferenced_position)

    # -- hooks -------------------------------------------------------------------------------
    def on_boot(self, now: float) -> None:
        if self.node.last_reset in ("power", "node"):
            self.sensor_error = False
            self._lose_reference()
        elif not self.referenced:
            self._lose_reference()

    def update_process(self, now: float) -> None:
        if not self.referenced or self.sensor_error:
            self.node.set(self.position.index, self.position.sub, self.unreferenced_position)

    def before_sdo_read(self, obj: ObjRef, now: float) -> int | None:
        if obj == self.position and (not self.referenced or self.sensor_error):
            return self.unreferenced_abort
        return None

    def before_sdo_write(self, obj: ObjRef, value: Any, now: float) -> int | None:
        if obj != self.command:
            return None
        if int(value) != self.command_value:
            return _ABORT_RANGE  # only the command value 1 is described (4.6.1.22)
        if self.sensor_error:
            return _ABORT_NO_DATA  # no measurement to reference while off the tape
        return None

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        if obj == self.command:
            self.reference(now)

    def reference(self, now: float) -> None:
        """5115h = 1: position value := calibration value 6003h at the current measurement."""
        measured = self._measurement(now)
        calibration = int(self.node.get(self.calibration.index, self.calibration.sub, 0) or 0)
        self.node.set_position_offset(calibration - measured)
        self.referenced = True
        self.references += 1
        # 6509h "Position value at the time of calibration" (UNSIGNED 32)
        self.node.set(self.offset.index, self.offset.sub, measured & 0xFFFFFFFF)
        self.node.set(self.status.index, self.status.sub, self.referenced_value)
        self._set_bit(self.flag_obj, self.flag_bit, False)
        self.node.set(self.position.index, self.position.sub, calibration)

    def on_fault(self, name: str, active: bool, now: float) -> bool:
        """``sensor_error``: encoder lifted off the tape (manual 2, 4.6.1.22, Table 9 FF10h)."""
        if name != "sensor_error":
            return False
        self.sensor_error = active
        self._set_bit(self.flag_obj, _SYS_READ_DISTANCE_BIT, active)
        if active:
            self._lose_reference()
            self.node.raise_emcy(_EMCY_TAPE, _REGISTER_ENCODER, now=now)
        else:
            self.node.clear_emcy(_EMCY_TAPE, now=now)
        return True
