"""DS-301 SDO abort codes and their texts.

Knows the table of abort codes (DS-301 V4.2, table "SDO abort codes"; the device manuals list
the subset each device uses, e.g. SGH10 manual 4.4.1.3 table 8) and how to word an unknown one.
Holds no exception classes: the typed errors are in ``gateway.errors``.

Imports: nothing.
"""

from __future__ import annotations

#: DS-301 SDO abort codes, 0503 0000h .. 0800 0024h.
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
    0x08000023: ("Object dictionary dynamic generation fails or no object dictionary is present"),
    0x08000024: "No data available",
}


def abort_text(code: int) -> str:
    """The DS-301 text of an abort code, or a text saying it is not a DS-301 code."""
    text = SDO_ABORT_TEXTS.get(code)
    if text is not None:
        return text
    return f"not a DS-301 abort code (manufacturer-specific 0x{code:08X}?)"
