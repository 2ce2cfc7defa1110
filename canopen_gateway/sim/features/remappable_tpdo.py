"""Variable TPDO mapping exactly by the procedure of MSK5000CAN manual 4.3.1.2.

The manual's six steps, for TPDO n with communication object 180xh and mapping object 1A0xh:

  1. the node is PRE-OPERATIONAL (4.2.1.1: "COB ID and Transmit PDO Mapping parameters cannot
     be changed" in OPERATIONAL);
  2. 180xh:01 written with the valid bit 31 = 1: the PDO is deactivated;
  3. 1A0xh:00 written with 0: the mapping is deactivated;
  4. 1A0xh:01.. written with the mapping entries (index << 16 | sub << 8 | bits);
  5. 1A0xh:00 written with the highest sub-index used: the mapping is enabled;
  6. 180xh:01 written with bit 31 = 0: the PDO is reactivated (with the new layout).

A write out of this order is refused with the abort code the profile's feature parameters give
(``abort_wrong_nmt_state``, ``abort_pdo_valid``, ``abort_mapping_enabled``,
``abort_cob_id_change_while_valid``, ``abort_not_mappable``, ``abort_too_long``; manual 4.4.1.3
Table 8). The manual's frames write the 8-bit 1A0xh:00 with command 23h (4 bytes): such
expedited downloads to these objects are accepted when the surplus bytes are zero.

The node builds each TPDO from the current 1A0xh values, so a reactivated PDO carries the new
layout from its next transmission. This module keeps no state of its own: the step reached is
what the objects say (see :meth:`RemappableTpdo.state`).

Imports: python-can (Message), canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref, canopen_gateway.sim.features, canopen_gateway.sim.objects.
"""

from __future__ import annotations

import struct
from typing import Any

import can

from canopen_gateway.canopen.cia301 import COB_ID_INVALID
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register
from canopen_gateway.sim.objects import bit_size, type_size

# NMT state byte of PRE-OPERATIONAL (MSK5000CAN manual 4.5.3)
_PRE_OPERATIONAL = 0x7F
_STOPPED = 0x04
# CiA 301: COB-ID bit 31 = 1 -> PDO does not exist / is not valid (manual 4.1)
_COB_ID_BITS = 0x3FFFFFFF  # bits 0..29: the CAN-ID and the 29-bit frame flag
# Defaults when the profile gives no code (manual 4.4.1.3 Table 8)
_DEFAULT_ABORTS = {
    "abort_wrong_nmt_state": 0x08000022,
    "abort_pdo_valid": 0x08000022,
    "abort_mapping_enabled": 0x08000022,
    "abort_cob_id_change_while_valid": 0x08000022,
    "abort_not_mappable": 0x06040041,
    "abort_too_long": 0x06040042,
}
_MAX_BYTES = 8  # manual 4.3.1.2: "A maximum of 8 data bytes can be mapped in a PDO"


@register
class RemappableTpdo(SimFeature):
    """Guards 180xh:01 and 1A0xh writes by the 4.3.1.2 procedure."""

    feature = "remappable_tpdo"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        # TPDO number -> (communication index, mapping index)
        self.pdos: dict[int, tuple[int, int]] = {}
        for number, spec in (params.get("tpdos") or {1: {}, 2: {}}).items():
            n = int(number)
            comm = ObjRef.parse(spec.get("communication", 0x1800 + n - 1)).index
            mapping = ObjRef.parse(spec.get("mapping", 0x1A00 + n - 1)).index
            self.pdos[n] = (comm, mapping)
        self._by_comm = {c: n for n, (c, _) in self.pdos.items()}
        self._by_map = {m: n for n, (_, m) in self.pdos.items()}
        self.max_bytes = int(params.get("max_bytes", _MAX_BYTES))
        self.max_entries = int(params.get("max_entries", 8))

    # -- helpers -----------------------------------------------------------------------------
    def _abort(self, name: str) -> int:
        code = self.params.get(name)
        return int(code) if code is not None else _DEFAULT_ABORTS[name]

    def _guarded(self, index: int, sub: int) -> bool:
        return (index in self._by_comm and sub == 1) or index in self._by_map

    def _pdo_valid(self, number: int) -> bool:
        comm, _ = self.pdos[number]
        return not int(self.node.get(comm, 1, COB_ID_INVALID)) & COB_ID_INVALID

    def state(self, number: int) -> str:
        """Where TPDO ``number`` stands in the procedure, as its objects say: ``"valid"``
        (in service), ``"deactivated"`` (after step 2 or 5: bit 31 set, mapping enabled) or
        ``"mapping_disabled"`` (after step 3: entries may be written)."""
        _, mapping = self.pdos[number]
        if self._pdo_valid(number):
            return "valid"
        return "mapping_disabled" if int(self.node.get(mapping, 0, 0)) == 0 else "deactivated"

    def _entry_error(self, raw: int) -> str | None:
        """None if ``raw`` may be mapped, else the name of the abort to answer."""
        if raw == 0:
            return None
        index, sub, bits = (raw >> 16) & 0xFFFF, (raw >> 8) & 0xFF, raw & 0xFF
        var = self.node.values.vars.get((index, sub))
        if var is None or not var.pdo_mappable:
            return "abort_not_mappable"
        size = bit_size(var)
        if bits == 0 or bits % 8 or (size and bits > size):
            return "abort_not_mappable"
        return None

    # -- hooks -------------------------------------------------------------------------------
    def before_sdo_write(self, obj: ObjRef, value: Any, now: float) -> int | None:
        index, sub = obj
        if not self._guarded(index, sub):
            return None
        # step 1: PRE-OPERATIONAL only
        if int(self.node.nmt_state) != _PRE_OPERATIONAL:
            return self._abort("abort_wrong_nmt_state")
        if index in self._by_comm:
            # steps 2 and 6: the CAN-ID changes only while the PDO is deactivated
            old = int(self.node.get(index, 1, COB_ID_INVALID))
            new = int(value)
            if not old & COB_ID_INVALID and not new & COB_ID_INVALID:
                if (old ^ new) & _COB_ID_BITS:
                    return self._abort("abort_cob_id_change_while_valid")
            return None
        number = self._by_map[index]
        # steps 3-5 need step 2: the PDO deactivated
        if self._pdo_valid(number):
            return self._abort("abort_pdo_valid")
        if sub == 0:
            # step 3 (0) or step 5 (highest sub-index used)
            count = int(value)
            if count == 0:
                return None
            if count > self.max_entries:
                return self._abort("abort_too_long")
            total_bits = 0
            for s in range(1, count + 1):
                raw = int(self.node.get(index, s, 0))
                error = self._entry_error(raw) if raw else "abort_not_mappable"
                if error is not None:
                    return self._abort(error)
                total_bits += raw & 0xFF
            if total_bits > 8 * self.max_bytes:
                return self._abort("abort_too_long")
            return None
        # step 4 needs step 3: the mapping deactivated
        if int(self.node.get(index, 0, 0)) != 0:
            return self._abort("abort_mapping_enabled")
        error = self._entry_error(int(value))
        return self._abort(error) if error is not None else None

    def frame_cob_ids(self) -> tuple[int, ...]:
        return (int(self.node.get(0x1200, 1, 0x600 + self.node.node_id)) & 0x7FF,)

    def on_frame(self, msg: can.Message, now: float) -> bool:
        """Accept the manual's 23h (4-byte) downloads to the 8/16-bit PDO parameters.

        Manual 4.3.1.2 writes 1A0xh:00 (UNSIGNED 8) with command 23h. The frame is handed to
        the node's SDO server as the expedited download of the object's real size when the
        surplus bytes are zero; anything else goes to the node unchanged.
        """
        if msg.is_remote_frame or msg.is_extended_id or len(msg.data) < 8:
            return False
        if int(self.node.nmt_state) == _STOPPED:
            return False
        rx_cob = int(self.node.get(0x1200, 1, 0x600 + self.node.node_id)) & 0x7FF
        if msg.arbitration_id != rx_cob:
            return False
        cmd = msg.data[0]
        if cmd & 0xE3 != 0x23:  # initiate download, expedited, size indicated
            return False
        index, sub = struct.unpack_from("<HB", msg.data, 1)
        if index not in self._by_comm and index not in self._by_map:
            return False
        var = self.node.values.vars.get((index, sub))
        size = type_size(var) if var is not None else None
        given = 4 - ((cmd >> 2) & 0x03)
        if size is None or given <= size or any(msg.data[4 + size : 4 + given]):
            return False
        data = bytes([0x23 | ((4 - size) << 2)]) + bytes(msg.data[1 : 4 + size])
        response = self.node.sdo.on_request(data.ljust(8, b"\0"), now)
        if response is not None:
            tx_cob = int(self.node.get(0x1200, 2, 0x580 + self.node.node_id)) & 0x7FF
            self.node.send(tx_cob, response)
        return True
