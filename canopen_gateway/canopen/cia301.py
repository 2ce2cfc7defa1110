"""CANopen facts (CiA 301 V4.2) in one place: function codes of the pre-defined connection set,
PDO COB-ID bits, the error-control objects, NMT command specifiers, data type codes with their
sizes, the error register bits, SDO command specifiers, SDO abort codes and their texts.

Rule: a number that CiA 301 defines is written here once, named, with the section it comes from;
every other module imports it from here (the device manuals repeat these tables: SGH10 manual
4.2.1.2 table 3 and AP05 manual 5.2.1.2 table 23 for NMT, SGH10 manual 4.4.1.3 table 8 for the
abort codes). Device-specific numbers stay with the device's profile.

Imports: canopen.objectdictionary.datatypes (the data type codes), canopen_gateway.canopen.code_text (the base
of the enums whose members carry a text), canopen_gateway.canopen.objref (the error-control objects).
Nothing else of the gateway.
"""

from __future__ import annotations

from enum import IntEnum

from canopen.objectdictionary import datatypes as dt

from canopen_gateway.canopen.code_text import CodeText
from canopen_gateway.canopen.objref import ObjRef

# --------------------------------------------------------------------------- function codes
# CiA 301 7.3.3 pre-defined connection set (11-bit CAN-ID = function code + node id)
COB_NMT = 0x000
COB_SYNC = 0x080  # default SYNC COB-ID (1005h)
COB_EMCY = 0x080  # + node id
COB_TIME = 0x100
COB_TPDO = (0x180, 0x280, 0x380, 0x480)  # TPDO1..4 + node id
COB_RPDO = (0x200, 0x300, 0x400, 0x500)  # RPDO1..4 + node id
COB_SDO_TX = 0x580  # + node id: server -> client (the device's answer)
COB_SDO_RX = 0x600  # + node id: client -> server (our request)
COB_NMT_EC = 0x700  # + node id: boot-up, heartbeat, node-guarding answer
COB_LSS_SLAVE = 0x7E4  # CiA 305: LSS slave -> master
COB_LSS_MASTER = 0x7E5  # CiA 305: LSS master -> slave
#: CiA 301 7.3.3 table 75: the node-specific functions of the pre-defined connection set, by
#: function code (the COB-ID of node n is code + n, n = 1..127)
PREDEFINED_FUNCTIONS: dict[int, str] = {
    COB_EMCY: "EMCY",
    COB_TPDO[0]: "TPDO1",
    COB_RPDO[0]: "RPDO1",
    COB_TPDO[1]: "TPDO2",
    COB_RPDO[1]: "RPDO2",
    COB_TPDO[2]: "TPDO3",
    COB_RPDO[2]: "RPDO3",
    COB_TPDO[3]: "TPDO4",
    COB_RPDO[3]: "RPDO4",
    COB_SDO_TX: "SDO response",
    COB_SDO_RX: "SDO request",
    COB_NMT_EC: "heartbeat",
}


def predefined_owner(cob_id: int) -> tuple[str, int] | None:
    """(function, node id) whose pre-defined COB-ID ``cob_id`` is: 0x181 -> ("TPDO1", 1);
    None for NMT, SYNC, TIME, LSS and ids outside the set."""
    base, node_id = cob_id & 0x780, cob_id & 0x7F
    name = PREDEFINED_FUNCTIONS.get(base)
    if name is None or node_id == 0 or cob_id > COB_ID_MASK_11BIT:
        return None
    return name, node_id


# --------------------------------------------------------------------------- PDO COB-ID bits
# CiA 301 7.5.2.35 / 7.5.2.37 (1400h.., 1800h.. sub-index 01h)
COB_ID_INVALID = 1 << 31  # bit 31 = 1: PDO does not exist / is not valid
COB_ID_NO_RTR = 1 << 30  # bit 30 = 1: no RTR allowed on this PDO
COB_ID_EXTENDED = 1 << 29  # bit 29 = 1: 29-bit CAN-ID
COB_ID_MASK_11BIT = 0x7FF
COB_ID_MASK_29BIT = 0x1FFFFFFF
#: CiA 301 7.5.2.5 (1005h, the SYNC COB-ID): bit 30 = 1, this node generates SYNC
SYNC_GENERATOR = 1 << 30
#: PDO communication and mapping parameter base indices (CiA 301 7.5.2.35..38)
PDO_COMM_BASE: dict[str, int] = {"rpdo": 0x1400, "tpdo": 0x1800}
PDO_MAP_BASE: dict[str, int] = {"rpdo": 0x1600, "tpdo": 0x1A00}
#: transmission types (CiA 301 7.5.2.35 table 71)
TRANSMISSION_RTR_ONLY = (252, 253)
#: synchronous: 0 acyclic (after an event, at the next SYNC), 1..240 every n-th SYNC; without a
#: SYNC producer such a TPDO is never sent
TRANSMISSION_SYNC = range(0, 241)
TRANSMISSION_EVENT = (254, 255)

# --------------------------------------------------------------------------- error control
# CiA 301 7.5.2: the objects a node is configured and supervised by (SGH10 manual 4.7.2.9,
# 4.7.2.10, 4.7.2.14; POSI+ manual 002 4: 1016h)
OBJ_GUARD_TIME = ObjRef(0x100C, 0x00)  # UNSIGNED16, ms
OBJ_LIFE_TIME_FACTOR = ObjRef(0x100D, 0x00)  # UNSIGNED8
OBJ_HEARTBEAT_CONSUMER = 0x1016  # sub 1..127: bits 0-15 time (ms), bits 16-23 producer node id
OBJ_HEARTBEAT_PRODUCER = ObjRef(0x1017, 0x00)  # UNSIGNED16, ms

# --------------------------------------------------------------------------- NMT


class NmtCommand(CodeText):
    """NMT command specifier, byte 0 of an NMT frame (CiA 301 7.2.8.3.1; SGH10 manual 4.2.1.2
    table 3; AP05 manual 5.2.1.2 table 23), each with its ``text``: the command's name as the
    CLI, Modbus HR 0, Zenoh and the web console spell it."""

    START = 0x01, "start"
    STOP = 0x02, "stop"
    ENTER_PRE_OPERATIONAL = 0x80, "preop"
    RESET_NODE = 0x81, "reset"
    RESET_COMMUNICATION = 0x82, "reset-comm"


#: the NMT commands by name, and the names by command specifier
NMT_COMMANDS: dict[str, int] = {c.text: int(c) for c in NmtCommand}
NMT_BY_CODE: dict[int, str] = {int(c): c.text for c in NmtCommand}

# --------------------------------------------------------------------------- data types
# CiA 301 7.4.7.1 table 44 (the codes are python canopen's ``datatypes``)
BOOLEAN = dt.BOOLEAN
REAL32 = dt.REAL32
REAL64 = dt.REAL64
VISIBLE_STRING = dt.VISIBLE_STRING
OCTET_STRING = dt.OCTET_STRING
UNICODE_STRING = dt.UNICODE_STRING
DOMAIN = dt.DOMAIN

#: data type code -> the gateway's signal type name (the types it serves); keyed so that the
#: ``data_type`` of a canopen variable (``int | None``) can be looked up as it is
TYPE_NAMES: dict[int | None, str] = {
    dt.BOOLEAN: "bool",
    dt.INTEGER8: "int8",
    dt.INTEGER16: "int16",
    dt.INTEGER32: "int32",
    dt.UNSIGNED8: "uint8",
    dt.UNSIGNED16: "uint16",
    dt.UNSIGNED32: "uint32",
    dt.REAL32: "float32",
    dt.VISIBLE_STRING: "string",
    dt.OCTET_STRING: "bytes",
    dt.INTEGER24: "int24",
    dt.INTEGER64: "int64",
    dt.UNSIGNED24: "uint24",
    dt.UNSIGNED64: "uint64",
    dt.REAL64: "float64",
    dt.INTEGER40: "int40",
    dt.INTEGER48: "int48",
    dt.INTEGER56: "int56",
    dt.UNSIGNED40: "uint40",
    dt.UNSIGNED48: "uint48",
    dt.UNSIGNED56: "uint56",
    dt.TIME_OF_DAY: "time_of_day",
    dt.TIME_DIFFERENCE: "time_difference",
}
#: bits of the fixed-size types; dummy entries 0001h..0007h of a PDO mapping map these too
TYPE_BITS: dict[int | None, int] = {
    dt.BOOLEAN: 1,
    dt.INTEGER8: 8,
    dt.INTEGER16: 16,
    dt.INTEGER32: 32,
    dt.UNSIGNED8: 8,
    dt.UNSIGNED16: 16,
    dt.UNSIGNED32: 32,
    dt.REAL32: 32,
    dt.INTEGER24: 24,
    dt.REAL64: 64,
    dt.INTEGER40: 40,
    dt.INTEGER48: 48,
    dt.INTEGER56: 56,
    dt.INTEGER64: 64,
    dt.UNSIGNED24: 24,
    dt.UNSIGNED40: 40,
    dt.UNSIGNED48: 48,
    dt.UNSIGNED56: 56,
    dt.UNSIGNED64: 64,
    dt.TIME_OF_DAY: 48,
    dt.TIME_DIFFERENCE: 48,
}
#: the signed integer types
SIGNED_TYPES: frozenset[int] = frozenset(dt.SIGNED_TYPES)
#: the time types (CiA 301 7.1.6.5 / 7.1.6.6), by their signal type names
TIME_TYPES: frozenset[str] = frozenset({"time_of_day", "time_difference"})
#: the numeric types the gateway decodes (integers of 8..64 bits, BOOLEAN, REAL32, REAL64)
NUMERIC_TYPES: frozenset[int] = frozenset(
    code
    for code, name in TYPE_NAMES.items()
    if code is not None and name not in ("string", "bytes") and name not in TIME_TYPES
)

# --------------------------------------------------------------------------- time types
# CiA 301 7.1.6.5 TIME_OF_DAY and 7.1.6.6 TIME_DIFFERENCE: 48 bits, little endian on the bus:
# bits 0..27 milliseconds after midnight, bits 28..31 reserved (0), bits 32..47 days since
# 1984-01-01 (TIME_OF_DAY) or days (TIME_DIFFERENCE). The gateway keeps the 48-bit word as the
# raw value (as it travels in a PDO or an SDO), and converts at the edges (Modbus, Zenoh).
TIME_MS_BITS = 28
TIME_MS_MASK = (1 << TIME_MS_BITS) - 1
TIME_DAYS_SHIFT = 32
TIME_DAYS_MAX = 0xFFFF
MS_PER_DAY = 86_400_000
#: 1984-01-01 00:00 UTC (the TIME_OF_DAY epoch) in milliseconds since 1970-01-01 (Unix)
TIME_EPOCH_UNIX_MS = 5113 * MS_PER_DAY


def time_fields(word: int) -> tuple[int, int]:
    """(days, ms) of a TIME_OF_DAY / TIME_DIFFERENCE word (the reserved bits ignored)."""
    return (word >> TIME_DAYS_SHIFT) & TIME_DAYS_MAX, word & TIME_MS_MASK


def time_ms(word: int) -> int:
    """The milliseconds a time word counts: days x 86 400 000 + ms (since 1984-01-01 for a
    TIME_OF_DAY, the duration for a TIME_DIFFERENCE)."""
    days, ms = time_fields(word)
    return days * MS_PER_DAY + ms


def time_word(total_ms: int) -> int:
    """The time word of ``total_ms`` milliseconds (the inverse of ``time_ms``); ValueError
    when it is negative or beyond 65535 days."""
    days, ms = divmod(int(total_ms), MS_PER_DAY)
    if total_ms < 0 or days > TIME_DAYS_MAX:
        raise ValueError(f"{total_ms} ms is outside 0..{(TIME_DAYS_MAX + 1) * MS_PER_DAY - 1} ms")
    return days << TIME_DAYS_SHIFT | ms


# --------------------------------------------------------------------------- EMCY
# CiA 301 7.5.2.2 (object 1001h, carried in byte 2 of every EMCY frame)
#: error register (1001h) bits
ERROR_REGISTER_BITS: dict[int, str] = {
    0: "generic",
    1: "current",
    2: "voltage",
    3: "temperature",
    4: "communication",
    5: "device profile specific",
    6: "reserved",
    7: "manufacturer specific",
}


def register_bits(register: int) -> list[str]:
    """Names of the bits set in an error register (1001h) value."""
    return [name for bit, name in ERROR_REGISTER_BITS.items() if register & (1 << bit)]


# --------------------------------------------------------------------------- SDO command specifiers
# CiA 301 7.2.4.3 (byte 0 of an SDO frame, bits 7..5; AP05 manual table 32): the client's and
# the server's specifiers are two sets, the same number means another service in each


class SdoCcs(IntEnum):
    """Client command specifier: byte 0 of a request, bits 7..5."""

    DOWNLOAD_SEGMENT = 0x00
    INITIATE_DOWNLOAD = 0x20
    INITIATE_UPLOAD = 0x40
    UPLOAD_SEGMENT = 0x60
    ABORT = 0x80


class SdoScs(IntEnum):
    """Server command specifier: byte 0 of an answer, bits 7..5."""

    UPLOAD_SEGMENT = 0x00
    DOWNLOAD_SEGMENT = 0x20
    INITIATE_UPLOAD = 0x40
    INITIATE_DOWNLOAD = 0x60
    ABORT = 0x80


# --------------------------------------------------------------------------- SDO abort codes
#: CiA 301 7.2.4.3.17 table 22, 0503 0000h .. 0800 0024h
SDO_ABORT_TEXTS: dict[int, str] = {
    0x05030000: "Toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "Client/server command specifier not valid or unknown",
    0x05040002: "Invalid block size (block mode only)",
    0x05040003: "Invalid sequence number (block mode only)",
    0x05040004: "CRC error (block mode only)",
    0x05040005: "Out of memory",
    0x06010000: "Unsupported access to an object",
    0x06010001: "Attempt to read a write only object",
    0x06010002: "Attempt to write a read only object",
    0x06020000: "Object does not exist in the object dictionary",
    0x06040041: "Object cannot be mapped to the PDO",
    0x06040042: "The number and length of the objects to be mapped would exceed PDO length",
    0x06040043: "General parameter incompatibility reason",
    0x06040047: "General internal incompatibility in the device",
    0x06060000: "Access failed due to a hardware error",
    0x06070010: "Data type does not match, length of service parameter does not match",
    0x06070012: "Data type does not match, length of service parameter too high",
    0x06070013: "Data type does not match, length of service parameter too low",
    0x06090011: "Sub-index does not exist",
    0x06090030: "Invalid value for parameter (download only)",
    0x06090031: "Value of parameter written too high (download only)",
    0x06090032: "Value of parameter written too low (download only)",
    0x06090036: "Maximum value is less than minimum value",
    0x060A0023: "Resource not available: SDO connection",
    0x08000000: "General error",
    0x08000020: "Data cannot be transferred or stored to the application",
    0x08000021: (
        "Data cannot be transferred or stored to the application because of local control"
    ),
    0x08000022: (
        "Data cannot be transferred or stored to the application because of the present "
        "device state"
    ),
    0x08000023: "Object dictionary dynamic generation fails or no object dictionary is present",
    0x08000024: "No data available",
}
SDO_ABORT_TIMEOUT = 0x05040000
SDO_ABORT_NO_OBJECT = 0x06020000
SDO_ABORT_TYPE_LENGTH = 0x06070010  # data type does not match, length does not match
SDO_ABORT_NO_SUBINDEX = 0x06090011
SDO_ABORT_DEVICE_STATE = 0x08000022  # not stored because of the present device state


def abort_text(code: int) -> str:
    """The CiA 301 text of an abort code, or a text saying it is not a CiA 301 code."""
    text = SDO_ABORT_TEXTS.get(code)
    if text is not None:
        return text
    return f"not a DS-301 abort code (manufacturer-specific 0x{code:08X}?)"
