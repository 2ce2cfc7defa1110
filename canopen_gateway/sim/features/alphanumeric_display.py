"""Feature ``alphanumeric_display``: both display rows written freely (AP05 manual 4.1.2,
5.3.1.2, 5.3.2, 5.3.3, 5F1Bh:02 = 3, 5F1Ch).

In the alpha-numeric mode set point1 (RPDO1) is row 1 and set point2 (RPDO2) row 2. Control
bit 7 (data identifier) says whether the six set-point bytes (bytes 0-3 and 4-5 of the RPDO)
are ASCII characters or a number. A valid set point (control bit 2 / 9) is shown flashing until
it is acknowledged: control bit 10 acknowledges row 1, bit 6 row 2, or the key (both rows at
once when neither was acknowledged). Without a valid set point row 1 is blank and row 2 shows
"---" (4.1.2). Status word in this mode (Table 28): bit 5 row 1 acknowledged, bit 3 row 2
acknowledged, bit 9 data identifier ASCII; arrows, windows and deviation stay 0.

``rows`` holds what the display shows, ``acknowledged`` the acknowledgement of each row.

Parameters (profile ``features: alphanumeric_display:``): mode_object, mode_value,
data_identifier_bit, status_data_identifier_bit, text_length, rows {n: {rpdo, chars_1_4,
chars_5_6}}, acknowledge_control_bits, acknowledged_status_bits.

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

_BLANK = {1: "", 2: "---"}  # 4.1.2: no valid set point
_VALID_BITS = {1: 2, 2: 9}  # control word Table 27: validity of set point1 / set point2
_OWNED_STATUS_BITS = (0, 1, 3, 4, 5, 6, 9)


def _ints(d: Any, default: dict[int, int]) -> dict[int, int]:
    return {int(k): int(v) for k, v in (d or default).items()}


@register
class AlphanumericDisplay(SimFeature):
    feature = "alphanumeric_display"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.mode_obj = ObjRef.parse(params.get("mode_object", "0x5F1B:02"))
        self.mode_value = int(params.get("mode_value", 3))
        self.control_obj = ObjRef.parse(params.get("control_word", "0x5F0C:00"))
        self.status_obj = ObjRef.parse(params.get("status_word", "0x5F19:00"))
        self.data_id_bit = int(params.get("data_identifier_bit", 7))
        self.status_data_id_bit = int(params.get("status_data_identifier_bit", 9))
        self.text_length = int(params.get("text_length", 6))
        rows = params.get("rows") or {
            1: {"rpdo": 1, "chars_1_4": "0x5F16:03", "chars_5_6": "0x5F16:04"},
            2: {"rpdo": 2, "chars_1_4": "0x5F16:01", "chars_5_6": "0x5F16:02"},
        }
        self.row_spec = {
            int(n): (int(r["rpdo"]), ObjRef.parse(r["chars_1_4"]), ObjRef.parse(r["chars_5_6"]))
            for n, r in rows.items()
        }
        self.ack_control = _ints(params.get("acknowledge_control_bits"), {1: 10, 2: 6})
        self.ack_status = _ints(params.get("acknowledged_status_bits"), {1: 5, 2: 3})
        pi = node.profile.profile.features.get("position_indicator") or {}
        self.valid_bits = _ints(pi.get("control_set_point_valid_bit"), _VALID_BITS)
        self.rows: dict[int, str] = {}
        self.acknowledged: dict[int, bool] = {}
        self._reset_rows()

    def _reset_rows(self) -> None:
        self.rows = {n: _BLANK.get(n, "") for n in self.row_spec}
        self.acknowledged = {n: False for n in self.row_spec}

    def active(self) -> bool:
        return int(self.node.get(*self.mode_obj, 0)) == self.mode_value

    def on_boot(self, now: float) -> None:
        if self.node.last_reset != "communication":
            self._reset_rows()

    def on_rpdo(self, number: int, data: bytes, now: float) -> None:
        if not self.active():
            return
        control = int(self.node.get(*self.control_obj, 0))
        for n, (rpdo, lo_obj, hi_obj) in self.row_spec.items():
            if rpdo != number:
                continue
            if control >> self.valid_bits.get(n, _VALID_BITS.get(n, 2)) & 1:
                lo = int(self.node.get(*lo_obj, 0)) & 0xFFFFFFFF
                hi = int(self.node.get(*hi_obj, 0)) & 0xFFFF
                raw = lo.to_bytes(4, "little") + hi.to_bytes(2, "little")
                if control >> self.data_id_bit & 1:
                    text = raw[: self.text_length].decode("ascii", "replace").rstrip("\0")
                else:
                    text = str(lo - (1 << 32) if lo & 0x80000000 else lo)
                if text != self.rows[n]:
                    self.rows[n] = text
                    self.acknowledged[n] = False
            else:
                self.rows[n] = _BLANK.get(n, "")
                self.acknowledged[n] = False
        for n, bit in self.ack_control.items():
            if control >> bit & 1 and n in self.acknowledged:
                self.acknowledged[n] = True
        self.node.invalidate_process()

    def acknowledge_by_key(self) -> None:
        """The acknowledgement key (4.1.2): both rows at once."""
        for n in self.acknowledged:
            self.acknowledged[n] = True
        self.node.invalidate_process()

    def update_process(self, now: float) -> None:
        if not self.active():
            return
        status = int(self.node.get(*self.status_obj, 0))
        for b in _OWNED_STATUS_BITS:
            status &= ~(1 << b)
        for n, bit in self.ack_status.items():
            if self.acknowledged.get(n):
                status |= 1 << bit
        if int(self.node.get(*self.control_obj, 0)) >> self.data_id_bit & 1:
            status |= 1 << self.status_data_id_bit
        self.node.set(*self.status_obj, status)
