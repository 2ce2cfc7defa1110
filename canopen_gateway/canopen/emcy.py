"""EMCY (emergency) frames decoded, with their texts (CiA 301 7.2.7).

An EMCY frame (COB-ID 80h + node id by default, object 1014h) carries 8 bytes (SGH10 manual
4.5.1, AP05 manual 5.5.1, DS-301): bytes 0-1 the error code (UNSIGNED16, little endian), byte 2
the error register (object 1001h), bytes 3-7 a manufacturer-specific field. Error code 0000h
signals that an error cause was removed.

Texts come from the device profile's ``emcy`` table first (the manual's own words), else from
the DS-301 generic error code classes below. Pure functions: the per-node history is the bus's
(``bus/emcy.py``).

Imports: canopen.cia301 (the error register bits) and the standard library. Must not import
python-can, canopen, logging or any other gateway module.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from canopen_gateway.canopen.cia301 import register_bits

#: DS-301 emergency error codes: exact codes defined by DS-301.
_DS301_EXACT: dict[int, str] = {
    0x0000: "Error reset or no error",
    0x1000: "Generic error",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "Life guard error or heartbeat error",
    0x8140: "Recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "Unexpected SYNC data length",
    0x8250: "RPDO timeout",
}

#: DS-301 emergency error code classes by high byte (``code & 0xFF00``).
_DS301_SUBCLASS: dict[int, str] = {
    0x0000: "Error reset or no error",
    0x1000: "Generic error",
    0x2000: "Current",
    0x2100: "Current, device input side",
    0x2200: "Current inside the device",
    0x2300: "Current, device output side",
    0x3000: "Voltage",
    0x3100: "Mains voltage",
    0x3200: "Voltage inside the device",
    0x3300: "Output voltage",
    0x4000: "Temperature",
    0x4100: "Ambient temperature",
    0x4200: "Device temperature",
    0x5000: "Device hardware",
    0x6000: "Device software",
    0x6100: "Internal software",
    0x6200: "User software",
    0x6300: "Data set",
    0x7000: "Additional modules",
    0x8000: "Monitoring",
    0x8100: "Communication",
    0x8200: "Protocol error",
    0x9000: "External error",
    0xF000: "Additional functions",
    0xFF00: "Device specific",
}


def generic_text(code: int) -> str:
    """The DS-301 text for an error code: exact code, else its class, else 'unknown class'."""
    text = _DS301_EXACT.get(code)
    if text is not None:
        return text
    text = _DS301_SUBCLASS.get(code & 0xFF00)
    if text is not None:
        return text
    text = _DS301_SUBCLASS.get(code & 0xF000)
    if text is not None:
        return text
    return f"error code 0x{code:04X} of a class DS-301 does not define"


def emcy_text(code: int, texts: Mapping[int, str] | None = None) -> str:
    """The profile's text for ``code`` (the manual's words), else the DS-301 generic text."""
    if texts:
        text = texts.get(code)
        if text:
            return text
    return generic_text(code)


@dataclass(frozen=True)
class Emcy:
    """One decoded EMCY frame."""

    code: int
    register: int  # error register, object 1001h
    manufacturer: bytes  # bytes 3..7
    text: str
    timestamp: float = 0.0

    @property
    def is_reset(self) -> bool:
        """Error code 0000h: an error cause was removed (SGH10 manual 4.5.1)."""
        return self.code == 0x0000

    @property
    def generic(self) -> str:
        return generic_text(self.code)

    @property
    def register_bits(self) -> list[str]:
        return register_bits(self.register)

    def __str__(self) -> str:
        bits = ", ".join(self.register_bits) or "none"
        return (
            f"EMCY 0x{self.code:04X} ({self.text}), error register 0x{self.register:02X} "
            f"[{bits}], manufacturer {self.manufacturer.hex(' ') or '-'}"
        )


def decode_emcy(
    data: bytes, texts: Mapping[int, str] | None = None, timestamp: float = 0.0
) -> Emcy:
    """Decode the data of an EMCY frame (at least code and error register: 3 bytes)."""
    if len(data) < 3:
        raise ValueError(f"EMCY frame with {len(data)} bytes; needs at least 3 (code, register)")
    code = data[0] | (data[1] << 8)
    return Emcy(code, data[2], bytes(data[3:8]), emcy_text(code, texts), timestamp)
