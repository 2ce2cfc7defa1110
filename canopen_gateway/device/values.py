"""SDO values: DS-301 type names and the bytes of a value in an SDO transfer.

The one encoding of values for SDO downloads and decoding of uploads, used by the boot steps,
the command service and the CLI. The time types (TIME_OF_DAY, TIME_DIFFERENCE, CiA 301
7.1.6.5/6) travel as their 48-bit word, little endian, and are that word here too.

Imports: the standard library only.
"""

from __future__ import annotations

import struct
from typing import Any

_PACK: dict[str, str] = {
    "bool": "<B",  # DS-301 BOOLEAN travels as one byte in an SDO
    "int8": "<b",
    "uint8": "<B",
    "int16": "<h",
    "uint16": "<H",
    "int32": "<i",
    "uint32": "<I",
    "int64": "<q",
    "uint64": "<Q",
    "float32": "<f",
    "float64": "<d",
}
#: the types without a ``struct`` code: bytes on the bus (CiA 301 7.1.4.5 / 7.1.6.5)
_INT_BYTES: dict[str, int] = {
    "int24": 3, "uint24": 3, "int40": 5, "uint40": 5, "int48": 6, "uint48": 6,
    "int56": 7, "uint56": 7, "time_of_day": 6, "time_difference": 6,
}  # fmt: skip
_FLOATS = ("float32", "float64")


def encode_value(value: int | float | str | bytes, type_: str) -> bytes:
    """Little-endian bytes of ``value`` as DS-301 type ``type_`` (profile type names)."""
    if isinstance(value, bytes):
        return value
    if type_ in ("string", "bytes"):
        return str(value).encode("ascii")
    size = _INT_BYTES.get(type_)
    if size is not None:
        try:
            return int(value).to_bytes(size, "little", signed=type_.startswith("int"))
        except OverflowError:
            raise ValueError(f"value {value!r} does not fit {type_}") from None
    fmt = _PACK.get(type_)
    if fmt is None:
        raise ValueError(f"unknown type {type_!r}")
    try:
        return struct.pack(fmt, float(value) if type_ in _FLOATS else int(value))
    except (struct.error, OverflowError):
        raise ValueError(f"value {value!r} does not fit {type_}") from None


def decode_value(data: bytes, type_: str) -> Any:
    """The value of an SDO upload's bytes as DS-301 type ``type_`` (profile type names).

    Strings are cut at the first trailing NUL (the SGH10 pads 1008h, manual 4.4.1.4)."""
    if type_ == "string":
        return data.rstrip(b"\0").decode("ascii", errors="replace")
    if type_ == "bytes":
        return data
    size = _INT_BYTES.get(type_)
    if size is not None:
        return int.from_bytes(data[:size], "little", signed=type_.startswith("int"))
    fmt = _PACK[type_]
    size = struct.calcsize(fmt)
    return struct.unpack(fmt, data[:size].ljust(size, b"\0"))[0]
