"""Command validation: what a value must be before the command service sends it south.

A raw value is checked against its type (and the width of a narrow PDO entry) and the
profile's range (``check_value``); the bits of a word a client may change are the profile's
``writable`` bits (``writable_mask``, named in refusals by ``bit_names``); an SDO value's
``type_`` is one of ``SDO_TYPES``. Pure: no I/O, no state.

Imports: errors, profiles.schema.
"""

from __future__ import annotations

import math
from typing import Any

from gateway.errors import ValueOutOfRange
from gateway.profiles.schema import TYPE_BITS, Signal

#: the types an SDO value may be read or written as (``type_`` of ``sdo_read`` / ``sdo_write``)
SDO_TYPES = (*TYPE_BITS, "string", "bytes")


def check_sdo_type(type_: str | None) -> None:
    """A ``type_`` no SDO value can have is a client's error, refused before anything is sent."""
    if type_ is not None and type_ not in SDO_TYPES:
        raise ValueError(f"type {type_!r} is not one of {', '.join(SDO_TYPES)}")


#: the largest finite REAL32 (IEEE 754 binary32)
REAL32_MAX = 3.4028234663852886e38


def type_range(type_: str, mapped_bits: int | None = None) -> tuple[int, int] | None:
    """The raw integers a ``type_`` holds; ``mapped_bits``: the width of a PDO entry narrower
    than the type (CiA 301 7.5.2.36), which then bounds the range."""
    bits = TYPE_BITS.get(type_)
    if bits is None or type_.startswith("float"):
        return None
    if mapped_bits is not None:
        bits = min(bits, mapped_bits)
    if type_ == "bool":
        return 0, 1
    if type_.startswith("int"):
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def check_value(sig: Signal, value: Any, mapped_bits: int | None = None) -> Any:
    """Validate a raw value for a signal; returns it normalised or raises ValueOutOfRange.
    ``mapped_bits``: the narrowest RPDO entry carrying the signal (see ``type_range``)."""
    if sig.type in ("string", "bytes"):
        if isinstance(value, str):
            try:
                raw = value.encode("ascii")
            except UnicodeEncodeError:
                raise ValueOutOfRange(sig.name, value, "ASCII text only") from None
        elif isinstance(value, (bytes, bytearray)):
            raw = bytes(value)
        else:
            raise ValueOutOfRange(sig.name, value, "text expected")
        if sig.length is not None and len(raw) > sig.length:
            raise ValueOutOfRange(sig.name, value, f"at most {sig.length} characters")
        if sig.type == "string" and any(b < 0x20 or b > 0x7E for b in raw.rstrip(b"\0")):
            raise ValueOutOfRange(sig.name, value, "printable ASCII characters only")
        return raw
    if sig.type in ("float32", "float64"):
        try:
            v: float | int = float(value)
        except (TypeError, ValueError):
            raise ValueOutOfRange(sig.name, value, "a number") from None
        if sig.type == "float32" and math.isfinite(v) and abs(v) > REAL32_MAX:
            raise ValueOutOfRange(sig.name, value, f"a REAL32 (magnitude <= {REAL32_MAX:g})")
    else:
        if isinstance(value, float) and not value.is_integer():
            raise ValueOutOfRange(sig.name, value, "an integer")
        try:
            v = int(value)
        except (TypeError, ValueError):
            raise ValueOutOfRange(sig.name, value, "an integer") from None
        rng = type_range(sig.type_name, mapped_bits)
        if rng and not rng[0] <= v <= rng[1]:
            narrow = mapped_bits is not None and mapped_bits < TYPE_BITS.get(sig.type_name, 64)
            what = f"{sig.type} mapped in {mapped_bits} bits" if narrow else sig.type
            raise ValueOutOfRange(sig.name, value, f"{rng[0]}..{rng[1]} ({what})")
    # profile min/max are engineering values (raw x scale + offset)
    eng = v * sig.scale + sig.offset
    if sig.min is not None and eng < sig.min - 1e-9:
        raise ValueOutOfRange(sig.name, value, f">= {sig.min:g} {sig.unit}".rstrip())
    if sig.max is not None and eng > sig.max + 1e-9:
        raise ValueOutOfRange(sig.name, value, f"<= {sig.max:g} {sig.unit}".rstrip())
    return v


def writable_mask(sig: Signal) -> int:
    """Bits of a word signal a client may set or clear (the profile's ``writable`` bits)."""
    mask = 0
    for b in sig.bits:
        if b.writable:
            mask |= ((1 << b.width) - 1) << b.bit
    return mask


def bit_names(sig: Signal, mask: int) -> str:
    names = []
    for bit in range(64):
        if mask >> bit & 1:
            named = next((b.name for b in sig.bits if b.bit <= bit < b.bit + b.width), None)
            names.append(f"bit {bit}" + (f" ({named})" if named else ""))
    return ", ".join(names)
