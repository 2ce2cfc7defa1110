"""The Modbus protocol itself, pure: function codes, exception codes, the quantity and length
rules of a request (Modbus Application Protocol V1.1b3, section 6), MBAP framing constants
(Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3), bit packing, and how a value of a
register-map point becomes registers and back (word order, types, strings).

Which gateway error becomes which exception code (``exception_code``) is here too: the one
mapping for every Modbus answer.

Imports: errors, northbound.regmap (the point's type and word order), northbound.scaling.
No I/O.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from enum import IntEnum
from typing import Any, TypeVar

from canopen_gateway.errors import (
    BusDown,
    NodeNotOperational,
    NodeUnknown,
    NotActive,
    ReadOnly,
    SdoAbort,
    SdoTimeout,
    Unmapped,
    ValueOutOfRange,
)
from canopen_gateway.northbound.regmap import Point, Table
from canopen_gateway.northbound.scaling import (
    scaled,
    time_register_ms,
    time_word_of_ms,
    unscaled_step,
)

T = TypeVar("T")


class ExceptionCode(IntEnum):
    """Modbus Application Protocol V1.1b3, section 7."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    SERVER_DEVICE_BUSY = 0x06
    GATEWAY_PATH_UNAVAILABLE = 0x0A
    GATEWAY_TARGET_FAILED_TO_RESPOND = 0x0B


# Function codes served (Modbus Application Protocol V1.1b3, 6.1-6.17)
READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING, READ_INPUT = 0x01, 0x02, 0x03, 0x04
WRITE_COIL, WRITE_REGISTER, WRITE_COILS, WRITE_REGISTERS = 0x05, 0x06, 0x0F, 0x10
MASK_WRITE_REGISTER, READ_WRITE_REGISTERS = 0x16, 0x17
ENCAPSULATED_INTERFACE = 0x2B  # 6.19-6.21; MEI type 14 Read Device Identification (identity.py)
READ_TABLE: dict[int, Table] = {READ_COILS: "co", READ_DISCRETE_INPUTS: "di", READ_HOLDING: "hr", READ_INPUT: "ir"}  # fmt: skip
WRITES = {WRITE_COIL, WRITE_REGISTER, WRITE_COILS, WRITE_REGISTERS, MASK_WRITE_REGISTER, READ_WRITE_REGISTERS}  # fmt: skip
SUPPORTED = {*READ_TABLE, *WRITES, ENCAPSULATED_INTERFACE}

# Quantity limits (Modbus Application Protocol V1.1b3, 6.1-6.4, 6.11, 6.12, 6.17)
MAX_READ_BITS = 0x07D0
MAX_READ_REGISTERS = 0x007D
MAX_WRITE_BITS = 0x07B0
MAX_WRITE_REGISTERS = 0x007B
MAX_RW_WRITE_REGISTERS = 0x0079
COIL_ON, COIL_OFF = 0xFF00, 0x0000  # 6.5: any other value is an illegal data value

# MBAP header (Modbus TCP Implementation Guide V1.0b, 3.1.3): transaction id, protocol id 0,
# length of the unit id + PDU (a PDU has at most 253 bytes, Application Protocol 4.1)
MBAP = struct.Struct(">HHHB")
MBAP_MIN_LENGTH = 2
MBAP_MAX_LENGTH = 254

#: requests of one connection processed at once; beyond, reading from it pauses
MAX_IN_FLIGHT = 16

#: a pair's standby says "unknown" for a node it did not hear started (bus.node.listening)
LIFECYCLE_CODES = {"waiting": 0, "booting": 1, "configuring": 2, "operational": 3, "unknown": 4}


class ModbusError(Exception):
    """A request answered with an exception code."""

    def __init__(self, code: ExceptionCode, why: str):
        self.code = code
        super().__init__(why)


def exception_code(exc: BaseException) -> ExceptionCode:
    """The Modbus answer to a typed error of the command service."""
    if isinstance(exc, ModbusError):
        return exc.code
    if isinstance(exc, NotActive):  # the standby of a pair: the active one takes commands
        return ExceptionCode.SERVER_DEVICE_BUSY
    if isinstance(exc, (ValueOutOfRange, ValueError, OverflowError)):
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if isinstance(exc, (ReadOnly, Unmapped)):
        return ExceptionCode.ILLEGAL_DATA_ADDRESS
    if isinstance(exc, SdoAbort):
        return ExceptionCode.SERVER_DEVICE_FAILURE
    if isinstance(exc, BusDown):
        return ExceptionCode.GATEWAY_PATH_UNAVAILABLE
    if isinstance(exc, (NodeNotOperational, NodeUnknown, SdoTimeout, TimeoutError)):
        return ExceptionCode.GATEWAY_TARGET_FAILED_TO_RESPOND
    return ExceptionCode.SERVER_DEVICE_FAILURE


#: the table of each read function in words (the log line of a refused read)
READ_WORDS = {READ_COILS: "coils", READ_DISCRETE_INPUTS: "discrete inputs",
              READ_HOLDING: "holding registers", READ_INPUT: "input registers"}  # fmt: skip


def read_range(fc: int, pdu: bytes) -> str:
    """What a read request asks for, in words: ``input registers 100-109`` (addresses from 0,
    as the PDU carries them); the function code alone for a request it cannot tell."""
    if fc in READ_WORDS and len(pdu) >= 5:
        address, qty = struct.unpack_from(">HH", pdu, 1)
        last = address + max(qty, 1) - 1
        return f"{READ_WORDS[fc]} {address}" + (f"-{last}" if last != address else "")
    return f"function 0x{fc:02X}"


# ---------------------------------------------------------------------- request checks (pure)
def check_request(fc: int, body: bytes) -> ExceptionCode | None:
    """None if the PDU (function code + ``body``) is well formed, else the exception to answer."""
    n = len(body)
    if fc not in SUPPORTED:
        return ExceptionCode.ILLEGAL_FUNCTION
    if fc in READ_TABLE:
        if n != 4:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        address, qty = struct.unpack(">HH", body)
        limit = MAX_READ_BITS if fc in (READ_COILS, READ_DISCRETE_INPUTS) else MAX_READ_REGISTERS
        if not 1 <= qty <= limit:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return ExceptionCode.ILLEGAL_DATA_ADDRESS if address + qty > 0x10000 else None
    if fc == WRITE_COIL:
        if n != 4:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        value = struct.unpack_from(">H", body, 2)[0]
        return None if value in (COIL_ON, COIL_OFF) else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc == WRITE_REGISTER:
        return None if n == 4 else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc == ENCAPSULATED_INTERFACE:  # MEI type, ReadDevId code, object id (6.21)
        return None if n == 3 else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc == MASK_WRITE_REGISTER:
        return None if n == 6 else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc in (WRITE_COILS, WRITE_REGISTERS):
        if n < 5:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        address, qty, byte_count = struct.unpack_from(">HHB", body)
        if fc == WRITE_COILS:
            ok = 1 <= qty <= MAX_WRITE_BITS and byte_count == (qty + 7) // 8
        else:
            ok = 1 <= qty <= MAX_WRITE_REGISTERS and byte_count == 2 * qty
        if not ok or n != 5 + byte_count:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return ExceptionCode.ILLEGAL_DATA_ADDRESS if address + qty > 0x10000 else None
    # READ_WRITE_REGISTERS
    if n < 9:
        return ExceptionCode.ILLEGAL_DATA_VALUE
    r_addr, r_qty, w_addr, w_qty, byte_count = struct.unpack_from(">HHHHB", body)
    if not (1 <= r_qty <= MAX_READ_REGISTERS and 1 <= w_qty <= MAX_RW_WRITE_REGISTERS):
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if byte_count != 2 * w_qty or n != 9 + byte_count:
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if r_addr + r_qty > 0x10000 or w_addr + w_qty > 0x10000:
        return ExceptionCode.ILLEGAL_DATA_ADDRESS
    return None


def pack_bits(bits: list[bool]) -> bytes:
    """Coils / discrete inputs: first bit in the LSB of the first byte (6.1)."""
    out = bytearray((len(bits) + 7) // 8)
    for i, b in enumerate(bits):
        if b:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(data: bytes, count: int) -> list[bool]:
    return [bool(data[i // 8] >> (i % 8) & 1) for i in range(count)]


# ---------------------------------------------------------------------- register encoding
def to_registers(value: Any, p: Point) -> list[int]:
    """A value as ``p.count`` registers: strings first character in the high byte, numbers
    with the point's word order, engineering points as float32 of raw x scale + offset."""
    t = p.type
    if t == "string":
        raw = (
            value
            if isinstance(value, (bytes, bytearray))
            else str(value).encode("ascii", "replace")
        )
        raw = bytes(raw)[: p.count * 2].ljust(p.count * 2, b"\0")
        return [(raw[i] << 8) | raw[i + 1] for i in range(0, len(raw), 2)]
    if p.engineering:
        value = scaled(float(value), p.scale, p.offset)
    if t == "float32":
        b = struct.pack(">f", float(value))
    elif t == "float64":
        b = struct.pack(">d", float(value))
    elif t in ("time_of_day", "time_difference"):  # docs/modbus.md: (Unix) ms as uint64
        b = time_register_ms(t, int(value)).to_bytes(8, "big")
    elif t in ("int16", "uint16"):
        return [int(value) & 0xFFFF]
    elif t in ("int32", "uint32"):
        b = (int(value) & 0xFFFFFFFF).to_bytes(4, "big")
    else:  # int64 / uint64
        b = (int(value) & 0xFFFFFFFFFFFFFFFF).to_bytes(8, "big")
    words = [int.from_bytes(b[i : i + 2], "big") for i in range(0, len(b), 2)]
    if p.word_order == "little":
        words.reverse()
    return words


def register_encoder(p: Point) -> Callable[[Any], list[int]]:
    """``to_registers`` for one point, made once: the common integer types without scaling
    as a direct expression (the per-request path of image reads), the rest through it."""
    t = p.type
    if not p.engineering and t in ("int16", "uint16"):
        return lambda value: [int(value) & 0xFFFF]
    if not p.engineering and t in ("int32", "uint32"):
        if p.word_order == "little":
            return lambda value: [int(value) & 0xFFFF, (int(value) >> 16) & 0xFFFF]
        return lambda value: [(int(value) >> 16) & 0xFFFF, int(value) & 0xFFFF]
    return lambda value: to_registers(value, p)


def from_registers(regs: list[int], p: Point) -> Any:
    """Registers written by a client back to a raw device value (inverse of to_registers)."""
    t = p.type
    if t == "string":
        raw = b"".join(r.to_bytes(2, "big") for r in regs)
        return raw.rstrip(b"\0")
    if t in ("int16", "uint16"):
        v = regs[0]
        if t == "int16" and v >= 0x8000:
            v -= 0x10000
        return v
    words = list(regs)
    if p.word_order == "little":
        words.reverse()
    b = b"".join(w.to_bytes(2, "big") for w in words)
    if t == "float32":
        f = struct.unpack(">f", b)[0]
        if p.engineering:
            # float -> raw integer: NaN / inf raise ValueError / OverflowError (0x03)
            return unscaled_step(f, p.scale, p.offset)
        return f
    if t == "float64":
        return struct.unpack(">d", b)[0]
    if t in ("time_of_day", "time_difference"):
        return time_word_of_ms(t, int.from_bytes(b, "big"))  # out of range: ValueError (0x03)
    return int.from_bytes(b, "big", signed=t.startswith("int"))
