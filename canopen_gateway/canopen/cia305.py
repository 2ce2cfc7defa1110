"""CiA 305 LSS (layer setting services) facts in one place, for both sides of the protocol: the
master (``bus.lss.master``) and the simulated slave (``sim.features.lss_slave``). The COB-IDs
(7E5h master -> slave, 7E4h slave -> master) are in ``cia301`` with the other COB-IDs.

Every LSS frame is 8 bytes, byte 0 the command specifier (cs), unused bytes 00h (SGH10 manual
4.6); ``lss_frame`` lays one out.

Imports: the standard library. Nothing of the gateway.
"""

from __future__ import annotations

# Command specifiers (SGH10 manual 4.6.1 - 4.6.3)
CS_SWITCH_GLOBAL = 0x04  # 4.6.1.1
CS_SWITCH_SELECTIVE_VENDOR = 0x40  # 4.6.1.2
CS_SWITCH_SELECTIVE_PRODUCT = 0x41
CS_SWITCH_SELECTIVE_REVISION = 0x42
CS_SWITCH_SELECTIVE_SERIAL = 0x43
CS_SWITCH_SELECTIVE_ANSWER = 0x44
CS_CONFIGURE_NODE_ID = 0x11  # 4.6.2.1
CS_CONFIGURE_BIT_TIMING = 0x13  # 4.6.2.2
CS_ACTIVATE_BIT_TIMING = 0x15  # 4.6.2.3
CS_STORE_CONFIGURATION = 0x17  # 4.6.2.4
CS_INQUIRE_VENDOR_ID = 0x5A  # 4.6.3.1
CS_INQUIRE_PRODUCT_CODE = 0x5B  # 4.6.3.2
CS_INQUIRE_REVISION = 0x5C  # 4.6.3.3
CS_INQUIRE_SERIAL = 0x5D  # 4.6.3.4
CS_INQUIRE_NODE_ID = 0x5E  # 4.6.3.5
CS_IDENTIFY_SLAVE = 0x4F  # CiA 305: the answer to Fast Scan and to identify remote slave (46h..4Bh)
CS_FAST_SCAN = 0x51  # CiA 305 Fast Scan: IDNumber, BitChecked, LSSSub, LSSNext
FAST_SCAN_RESET = 0x80  # BitChecked 80h: every unconfigured slave answers, back to part 0

#: Switch state global modes (4.6.1.1).
MODE_WAITING = 0x00
MODE_CONFIGURATION = 0x01

#: CiA 305 / DS-301 bit timing table (table selector 00h), SGH10 manual 4.6.2.2. Index 5 is
#: reserved; the SGH10 supports indices 0..7 only (8 = 10 kbit/s "not supported" there).
BIT_TIMING_KBPS: dict[int, int] = {0: 1000, 1: 800, 2: 500, 3: 250, 4: 125, 6: 50, 7: 20, 8: 10}
BIT_TIMING_TABLE_DS301 = 0x00


def lss_frame(cs: int, payload: bytes = b"") -> bytes:
    """cs + payload, filled with 00h to 8 bytes (SGH10 manual 4.6: unused bytes are 00h)."""
    return bytes([cs]) + payload.ljust(7, b"\0")
