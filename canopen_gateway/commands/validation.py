"""Command validation: what a value must be before the command service sends it south.

A raw value is checked against its type (and the width of a narrow PDO entry) and the
profile's range (``check_value``); the bits of a word a client may change are the profile's
``writable`` bits (``writable_mask``, named in refusals by ``bit_names``); an SDO value's
``type_`` is one of ``SDO_TYPES``. Pure: no I/O, no state.

Every configuration write (an SDO download a client asks for) also passes two checks:

* ``config_range_problem``: the object's range, from the EDS (LowLimit/HighLimit) and the
  profile's ``constraints`` (the device manual's words the EDS cannot say: SGH10 manual
  4.7.2.14, 1017h "0 or 10..65535");
* ``supervision_problem``: a write that would defeat the gateway's supervision of the node is
  refused (``SupervisionWrite``): 1017h on a node supervised by its heartbeat, 100Ch/100Dh
  (or 1017h other than 0, which takes precedence, CiA 301 7.2.8.3.2) on a node supervised by
  node guarding, and an entry of 1016h the boot configuration set to consume the master's
  heartbeat: each may only be written with the value the gateway configured. The way to change
  them is the node's configuration (``heartbeat_ms``, ``guard_time_ms``...).

Imports: errors, profiles.schema, canopen.cia301 (the error-control objects), canopen.objref; profiles, device.settings and device.boot_steps for types.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from canopen_gateway.canopen.cia301 import (
    OBJ_GUARD_TIME,
    OBJ_HEARTBEAT_CONSUMER,
    OBJ_HEARTBEAT_PRODUCER,
    OBJ_LIFE_TIME_FACTOR,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.errors import ValueOutOfRange
from canopen_gateway.profiles.schema import TYPE_BITS, Signal

if TYPE_CHECKING:
    from canopen_gateway.device.boot_steps import ConfigStep
    from canopen_gateway.device.settings import NodeSettings
    from canopen_gateway.profiles import LoadedProfile

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


# ---------------------------------------------------------------------- configuration writes
#: the objects the gateway supervises a node by (cia301's error-control objects; 1016h's entries
#: are tested by index)
SUPERVISION_OBJECTS = (OBJ_GUARD_TIME, OBJ_LIFE_TIME_FACTOR, OBJ_HEARTBEAT_PRODUCER)


def is_supervision_object(obj: ObjRef) -> bool:
    """1017h, 100Ch, 100Dh or an entry of 1016h: a write to it may change error control."""
    return obj in SUPERVISION_OBJECTS or (obj.index == OBJ_HEARTBEAT_CONSUMER and obj.sub > 0)


def config_range_problem(lp: LoadedProfile, obj: ObjRef, value: int) -> str | None:
    """Why an integer ``value`` is outside what ``obj`` accepts (EDS LowLimit/HighLimit, the
    profile's constraint), or None. An EDS whose limits say nothing (LowLimit > HighLimit, or
    both 0, as placeholder files have) is not read as a limit."""
    var = lp.od_var(obj)
    lo, hi = getattr(var, "min", None), getattr(var, "max", None)
    if lo is not None and hi is not None and (lo > hi or lo == hi == 0):
        lo = hi = None
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        shown = f"{lo if lo is not None else ''}..{hi if hi is not None else ''}"
        return f"{shown} (LowLimit/HighLimit of {obj} in {lp.eds_path.name})"
    c = lp.profile.constraints.get(obj)
    if c is not None and not c.admits(value):
        note = f"; {c.note}" if c.note else ""
        return f"{c.allowed} (profile {lp.profile.family}){note}"
    return None


def _configured(steps: Sequence[ConfigStep], obj: ObjRef, default: int) -> int:
    """The value the boot configuration writes to ``obj`` (its last step), else ``default``."""
    for step in reversed(steps):
        if step.object == obj and isinstance(step.value, int):
            return step.value
    return default


def supervision_problem(
    node: str,
    settings: NodeSettings,
    steps: Sequence[ConfigStep],
    master_node_id: int,
    obj: ObjRef,
    value: int,
) -> str | None:
    """Why writing ``value`` to ``obj`` would defeat the gateway's supervision of ``node``, or
    None. A write of the value the gateway configured changes nothing and is allowed."""
    kind = settings.supervision
    keep: int | None = None
    how = ""
    if obj == OBJ_HEARTBEAT_PRODUCER and kind == "heartbeat":
        keep = _configured(steps, obj, settings.heartbeat_ms)
        how = f"by its heartbeat: 1017h = {keep} ms (heartbeat_ms in the config)"
    elif obj == OBJ_HEARTBEAT_PRODUCER and kind == "guarding":
        keep = 0
        how = "by node guarding: 1017h = 0 (a heartbeat time takes precedence over guarding)"
    elif obj == OBJ_GUARD_TIME and kind == "guarding":
        keep = _configured(steps, obj, settings.guard_time_ms)
        how = f"by node guarding: 100Ch = {keep} ms (guard_time_ms in the config)"
    elif obj == OBJ_LIFE_TIME_FACTOR and kind == "guarding":
        keep = _configured(steps, obj, settings.life_time_factor)
        how = f"by node guarding: 100Dh = {keep} (life_time_factor in the config)"
    elif obj.index == OBJ_HEARTBEAT_CONSUMER and obj.sub > 0:
        configured = _configured(steps, obj, -1)
        if configured < 0 or (configured >> 16) & 0xFF != master_node_id:
            return None
        keep = configured
        how = (
            f"watching the master's heartbeat: {obj} = {keep:#010x} (node {master_node_id}, "
            f"{keep & 0xFFFF} ms; the node's sdo writes in the config)"
        )
    if keep is None or value == keep:
        return None
    return (
        f"node {node} is supervised {how}; writing {value} would change that "
        "(change the node's configuration instead)"
    )
