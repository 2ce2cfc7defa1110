"""Feature ``lss_slave``: CiA 305 Layer Setting Service slave, as the SGH10 manual 4.6 shows it.

Requests arrive on 7E5h and answers leave on 7E4h, always 8 bytes, command specifier in byte 0,
unused bytes 00h (manual 4.6). The slave is in one of two LSS states:

  state          request                                    -> effect / answer (7E4h)
  any            04h mode 00h switch state global           -> waiting (no answer; a node id
                                                               configured before applies at
                                                               the next NMT reset comm. 82h)
  any            04h mode 01h                               -> configuration (no answer)
  waiting        40h vendor, 41h product, 42h revision,     -> after all four matched 1018h:01
                 43h serial (switch state selective)           ..04 in this order:
                                                               configuration, answer 44h
  configuration  11h NID configure node id                  -> 11h 00h (01h..7Fh) / 11h 01h
  configuration  13h table index configure bit timing       -> 13h 00h (table 0, index of the
                                                               profile's list) / 13h 01h
  configuration  15h delay activate bit timing              -> silent for 2 x delay ms, then
                                                               boot-up at the new bit rate
  configuration  17h store configuration                    -> 17h 00h, node id and bit rate
                                                               stored (PersistentStore)
  configuration  5Ah/5Bh/5Ch/5Dh inquire identity           -> same cs, 1018h:01..04 LE
  configuration  5Eh inquire node id                        -> 5Eh NID (the active node id)
  waiting,       51h IDNumber BitChecked LSSSub LSSNext     -> 4Fh when BitChecked is 80h
  unconfigured   (CiA 305 Fast Scan)                           (reset: part 0) or part LSSSub
                                                               of 1018h equals IDNumber in
                                                               bits 31..BitChecked; then part
                                                               LSSNext; a full match (bit 0,
                                                               LSSNext < LSSSub): configuration

"Unconfigured" (the simulator option ``features: {lss_slave: {unconfigured: true}}``): a device
shipped without a node id, which answers Fast Scan until LSS configures one.

Anything else on 7E5h is ignored, as are services not allowed in the current state
(manual Table 10). Bit timing table (4.6.2.2): 0 1000, 1 800, 2 500, 3 250, 4 125, 6 50,
7 20 kbit/s; a simulator has no physical bit rate, ``bitrate_kbps`` reports the active one.

Imports: python-can (Message), canopen_gateway.canopen.cia301 (the LSS COB-IDs), canopen_gateway.canopen.cia305 (the command
specifiers, the bit timing table, the frame layout), canopen_gateway.sim.features.
"""

from __future__ import annotations

import struct
from typing import Any

import can

from canopen_gateway.canopen import cia305
from canopen_gateway.canopen.cia301 import COB_LSS_MASTER, COB_LSS_SLAVE
from canopen_gateway.sim.features import SimFeature, register

#: SGH10 manual 4.6.2.2: the bit timing indices a slave takes when its profile does not list
#: ``bit_timing_indices`` (8, 10 kbit/s, is "not supported" there)
DEFAULT_BIT_TIMING_INDICES = frozenset(cia305.BIT_TIMING_KBPS) - {8}

WAITING = "waiting"
CONFIGURATION = "configuration"


@register
class LssSlave(SimFeature):
    feature = "lss_slave"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.rx_cob = int(params.get("cob_id_master_to_slave", COB_LSS_MASTER))
        self.tx_cob = int(params.get("cob_id_slave_to_master", COB_LSS_SLAVE))
        self.table = int(params.get("bit_timing_table", cia305.BIT_TIMING_TABLE_DS301))
        self.indices = set(params.get("bit_timing_indices", DEFAULT_BIT_TIMING_INDICES))
        self.state = WAITING
        self._selective = 0  # how many of 40h..43h matched in order
        self.configured_node_id: int | None = None
        self.configured_bitrate_index: int | None = None
        self.active_bitrate_index: int | None = None
        self._boot_at_s: float | None = None
        self.unconfigured = bool(params.get("unconfigured", False))
        self._scan_part = 0  # CiA 305 Fast Scan: the part of the address compared next

    @property
    def bitrate_kbps(self) -> int | None:
        idx = self.active_bitrate_index
        return None if idx is None else cia305.BIT_TIMING_KBPS.get(idx)

    def identity(self, sub: int) -> int:
        """1018h:sub, with the profile's constants where it gives them (manual 4.6)."""
        key = {1: "vendor_id", 2: "product_code", 3: "revision_number", 4: "serial_number"}[sub]
        v = self.params.get(key)
        if isinstance(v, int):
            return v
        return int(self.node.get(0x1018, sub, 0))

    # -- hooks -------------------------------------------------------------------------------
    def on_boot(self, now: float) -> None:
        if self.node.last_reset == "power":
            self.state = WAITING
            self._selective = 0
            self.configured_node_id = None
            self.configured_bitrate_index = None
            self.active_bitrate_index = self.node.store.bitrate_index

    def tick(self, now: float) -> None:
        if self._boot_at_s is not None and now >= self._boot_at_s:
            # 4.6.2.3: after d2 the slave reports with the boot-up at the new bit rate
            self._boot_at_s = None
            self.node.mute(None)
            self.node.send(0x700 + self.node.node_id, b"\x00")

    def frame_cob_ids(self) -> tuple[int, ...]:
        return (self.rx_cob,)

    def on_frame(self, msg: can.Message, now: float) -> bool:
        if msg.arbitration_id != self.rx_cob or msg.is_remote_frame or msg.is_extended_id:
            return False
        data = bytes(msg.data).ljust(8, b"\0")
        cs = data[0]
        if cs == cia305.CS_SWITCH_GLOBAL:
            self._switch_global(data[1])
        elif cia305.CS_SWITCH_SELECTIVE_VENDOR <= cs <= cia305.CS_SWITCH_SELECTIVE_SERIAL:
            self._selective_step(cs, struct.unpack_from("<I", data, 1)[0])
        elif cs == cia305.CS_FAST_SCAN:
            self._fast_scan(data)
        elif self.state == CONFIGURATION:
            self._configuration_service(cs, data, now)
        return True

    # -- services ----------------------------------------------------------------------------
    def _answer(self, cs: int, *payload: int) -> None:
        self.node.send(self.tx_cob, cia305.lss_frame(cs, bytes(payload)))

    def _switch_global(self, mode: int) -> None:
        if mode == cia305.MODE_WAITING:
            if self.state == CONFIGURATION and self.configured_node_id is not None:
                if self.configured_node_id != self.node.node_id:
                    # 4.6.2.1: LSS waiting, then NMT reset communication activates the id
                    self.node.adopt_node_id_at_reset(self.configured_node_id)
            self.state = WAITING
        elif mode == cia305.MODE_CONFIGURATION:
            self.state = CONFIGURATION
        self._selective = 0

    def _selective_step(self, cs: int, value: int) -> None:
        if self.state != WAITING:
            return  # manual Table 10: selective switching only in LSS waiting
        step = cs - cia305.CS_SWITCH_SELECTIVE_VENDOR
        if step != self._selective or value != self.identity(step + 1):
            self._selective = 0
            return
        self._selective += 1
        if self._selective == 4:
            self._selective = 0
            self.state = CONFIGURATION
            self._answer(cia305.CS_SWITCH_SELECTIVE_ANSWER)

    def _fast_scan(self, data: bytes) -> None:
        """CiA 305 Fast Scan: only an unconfigured slave in LSS waiting takes part."""
        if self.state != WAITING or not self.unconfigured or self.configured_node_id is not None:
            return
        id_number = struct.unpack_from("<I", data, 1)[0]
        bit, part, next_part = data[5], data[6], data[7]
        if bit == cia305.FAST_SCAN_RESET:
            self._scan_part = 0
        elif bit > 31 or part > 3 or next_part > 3 or part != self._scan_part:
            return
        else:
            mask = (0xFFFFFFFF << bit) & 0xFFFFFFFF
            if (self.identity(part + 1) & mask) != (id_number & mask):
                return
            self._scan_part = next_part
            if bit == 0 and next_part < part:  # the whole address matched
                self.state = CONFIGURATION
        self._answer(cia305.CS_IDENTIFY_SLAVE)

    def _configuration_service(self, cs: int, data: bytes, now: float) -> None:
        if cs == cia305.CS_CONFIGURE_NODE_ID:
            nid = data[1]
            if 0x01 <= nid <= 0x7F:
                self.configured_node_id = nid
                self._answer(cs, 0x00, 0x00)
            else:
                self._answer(cs, 0x01, 0x00)  # 01h: no valid node id
        elif cs == cia305.CS_CONFIGURE_BIT_TIMING:
            selector, index = data[1], data[2]
            if selector == self.table and index in self.indices and index in cia305.BIT_TIMING_KBPS:
                self.configured_bitrate_index = index
                self._answer(cs, 0x00, 0x00)
            else:
                self._answer(cs, 0x01, 0x00)  # 01h: no valid baud rate
        elif cs == cia305.CS_ACTIVATE_BIT_TIMING:
            delay_ms = struct.unpack_from("<H", data, 1)[0]
            if self.configured_bitrate_index is not None:
                self.active_bitrate_index = self.configured_bitrate_index
            self._boot_at_s = now + 2 * delay_ms / 1000
            self.node.mute(self._boot_at_s)
        elif cs == cia305.CS_STORE_CONFIGURATION:
            store = self.node.store
            store.node_id = (
                self.configured_node_id or self.node.pending_node_id or self.node.node_id
            )
            if self.configured_bitrate_index is not None:
                store.bitrate_index = self.configured_bitrate_index
            self._answer(cs, 0x00, 0x00)
        elif cia305.CS_INQUIRE_VENDOR_ID <= cs <= cia305.CS_INQUIRE_SERIAL:
            value = self.identity(cs - cia305.CS_INQUIRE_VENDOR_ID + 1)
            self._answer(cs, *struct.pack("<I", value & 0xFFFFFFFF))
        elif cs == cia305.CS_INQUIRE_NODE_ID:
            self._answer(cs, self.node.node_id)
