"""PDO parameters and mapping of a simulated node (DS-301 7.2.2, 7.5.2.35-7.5.2.38).

Reads a node's *current* communication parameters (RPDO 1400h.., TPDO 1800h..) and mapping
(RPDO 1600h.., TPDO 1A00h..) from its object values, packs TPDO data from mapped objects and
unpacks RPDO data into them, and checks writes to these objects against the DS-301 rules
(a COB-ID is changed only while the PDO is invalid, bit 31; a mapping only while the PDO is
invalid and sub-index 0 is 0). It sends nothing and keeps no timers (node.py does).

Imports: canopen_gateway.canopen.cia301, canopen_gateway.sim.objects, canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from canopen_gateway.canopen.cia301 import (
    COB_ID_EXTENDED,
    COB_ID_INVALID,
    COB_ID_MASK_29BIT,
    PDO_COMM_BASE,
    PDO_MAP_BASE,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.objects import (
    ABORT_NOT_MAPPABLE,
    ABORT_PDO_LENGTH,
    ABORT_STATE,
    ObjectValues,
    SdoAbortError,
    bit_size,
    from_bits,
    to_bits,
)

Kind = Literal["rpdo", "tpdo"]


def comm_index(kind: Kind, number: int) -> int:
    return PDO_COMM_BASE[kind] + number - 1


def map_index(kind: Kind, number: int) -> int:
    return PDO_MAP_BASE[kind] + number - 1


def pdo_of(index: int) -> tuple[Kind, int, bool] | None:
    """(kind, number, is_mapping) for a PDO parameter index, else None."""
    for kind in ("rpdo", "tpdo"):
        k: Kind = kind
        if PDO_COMM_BASE[k] <= index < PDO_COMM_BASE[k] + 0x200:
            return k, index - PDO_COMM_BASE[k] + 1, False
        if PDO_MAP_BASE[k] <= index < PDO_MAP_BASE[k] + 0x200:
            return k, index - PDO_MAP_BASE[k] + 1, True
    return None


def numbers(values: ObjectValues, kind: Kind) -> list[int]:
    """PDO numbers (1-based) whose communication parameter exists in the EDS."""
    base = PDO_COMM_BASE[kind]
    return sorted(i - base + 1 for i in values.od.indices if base <= i < base + 0x200)


@dataclass(frozen=True)
class MapEntry:
    index: int
    sub: int
    bits: int

    @classmethod
    def decode(cls, raw: int) -> MapEntry:
        return cls((raw >> 16) & 0xFFFF, (raw >> 8) & 0xFF, raw & 0xFF)


def cob_id(values: ObjectValues, kind: Kind, number: int) -> int:
    return int(values.get(comm_index(kind, number), 1, COB_ID_INVALID))


def is_valid(values: ObjectValues, kind: Kind, number: int) -> bool:
    return not cob_id(values, kind, number) & COB_ID_INVALID


def transmission_type(values: ObjectValues, kind: Kind, number: int) -> int:
    return int(values.get(comm_index(kind, number), 2, 255))


def event_timer_ms(values: ObjectValues, number: int) -> int:
    return int(values.get(comm_index("tpdo", number), 5, 0))


def inhibit_time_100us(values: ObjectValues, number: int) -> int:
    return int(values.get(comm_index("tpdo", number), 3, 0))


def mapping(values: ObjectValues, kind: Kind, number: int) -> list[MapEntry]:
    """Current mapping entries in byte order (1A0xh/160xh sub 1..sub 0)."""
    idx = map_index(kind, number)
    count = int(values.get(idx, 0, 0))
    return [MapEntry.decode(int(values.get(idx, s, 0))) for s in range(1, count + 1)]


def length_bytes(entries: list[MapEntry]) -> int:
    return (sum(e.bits for e in entries) + 7) // 8


def pack(values: ObjectValues, entries: list[MapEntry]) -> bytes:
    """TPDO data from the mapped objects' current values (dummy entries < 1000h are 0)."""
    acc = 0
    shift = 0
    for e in entries:
        var = values.vars.get((e.index, e.sub)) if e.index >= 0x1000 else None
        acc |= to_bits(var, values.get(e.index, e.sub, 0), e.bits) << shift
        shift += e.bits
    return acc.to_bytes((shift + 7) // 8, "little")


@dataclass(frozen=True)
class TpdoParams:
    """TPDO ``number``'s communication parameters and mapping as they are now, with the mapping
    compiled to (object key, variable or None for a dummy, bits) for ``pack_compiled``. Valid
    until a PDO parameter object changes (the node drops it then)."""

    cob_id: int
    transmission_type: int
    inhibit_s: float
    event_timer_ms: int
    plan: tuple[tuple[tuple[int, int], Any, int], ...]


def tpdo_params(values: ObjectValues, number: int) -> TpdoParams:
    plan = tuple(
        ((e.index, e.sub), values.vars.get((e.index, e.sub)) if e.index >= 0x1000 else None, e.bits)
        for e in mapping(values, "tpdo", number)
    )
    return TpdoParams(
        cob_id(values, "tpdo", number),
        transmission_type(values, "tpdo", number),
        inhibit_time_100us(values, number) * 100e-6,
        event_timer_ms(values, number),
        plan,
    )


def pack_compiled(values: ObjectValues, plan: tuple[tuple[tuple[int, int], Any, int], ...]) -> bytes:
    """:func:`pack` with a mapping compiled by :func:`tpdo_params` (same bytes)."""
    acc = 0
    shift = 0
    get = values.values.get
    for key, var, bits in plan:
        acc |= to_bits(var, get(key, 0), bits) << shift
        shift += bits
    return acc.to_bytes((shift + 7) // 8, "little")


def unpack(values: ObjectValues, entries: list[MapEntry], data: bytes) -> list[tuple[ObjRef, Any]]:
    """(object, value) pairs an RPDO carries; dummy entries are skipped."""
    acc = int.from_bytes(data, "little")
    shift = 0
    out: list[tuple[ObjRef, Any]] = []
    for e in entries:
        raw = (acc >> shift) & ((1 << e.bits) - 1)
        shift += e.bits
        var = values.vars.get((e.index, e.sub)) if e.index >= 0x1000 else None
        if var is not None:
            out.append((ObjRef(e.index, e.sub), from_bits(var, raw, e.bits)))
    return out


def check_mapping_entry(values: ObjectValues, raw: int, *, require_mappable: bool) -> None:
    """DS-301: a mapped object must exist, fit its size and be PDO-mappable (0x06040041)."""
    e = MapEntry.decode(raw)
    if raw == 0:
        return
    if e.index < 0x1000:
        return  # dummy mapping of a data type (DS-301 0002h..0007h)
    var = values.vars.get((e.index, e.sub))
    if var is None:
        raise SdoAbortError(ABORT_NOT_MAPPABLE, f"{ObjRef(e.index, e.sub)} does not exist")
    size = bit_size(var)
    if require_mappable and not var.pdo_mappable:
        raise SdoAbortError(ABORT_NOT_MAPPABLE, f"{ObjRef(e.index, e.sub)} is not mappable")
    if size and e.bits > size:
        raise SdoAbortError(ABORT_NOT_MAPPABLE, f"{ObjRef(e.index, e.sub)} has {size} bits")


def check_write(
    values: ObjectValues, index: int, sub: int, value: Any, *, require_mappable: bool = False
) -> None:
    """DS-301 rules for writing a PDO parameter; raises SdoAbortError 0x08000022 and friends.

    - sub 1 (COB-ID): bits 0-29 may change only while the PDO is invalid (bit 31 set now or
      in the new value's predecessor), e.g. 0x80000181 first, then 0x00000182 is refused
      unless the stored value has bit 31 set (SGH10 manual 4.1).
    - mapping sub 0: only while the PDO is invalid; the entries 1..n must fit 64 bits.
    - mapping sub 1..: only while the PDO is invalid and sub 0 is 0.
    """
    which = pdo_of(index)
    if which is None:
        return
    kind, number, is_map = which
    if not is_map:
        if sub == 1:
            old = cob_id(values, kind, number)
            new = int(value)
            if not old & COB_ID_INVALID and not new & COB_ID_INVALID:
                if (old ^ new) & (COB_ID_MASK_29BIT | COB_ID_EXTENDED):
                    raise SdoAbortError(
                        ABORT_STATE, f"{ObjRef(index, 1)}: set bit 31 before changing the COB-ID"
                    )
        return
    if is_valid(values, kind, number):
        raise SdoAbortError(
            ABORT_STATE, f"{kind.upper()}{number} is valid: set bit 31 of its COB-ID first"
        )
    if sub == 0:
        count = int(value)
        total = 0
        for s in range(1, count + 1):
            if not values.has(index, s):
                raise SdoAbortError(ABORT_PDO_LENGTH, f"{ObjRef(index, 0)}: {count} entries")
            raw = int(values.get(index, s, 0))
            check_mapping_entry(values, raw, require_mappable=require_mappable)
            total += raw & 0xFF
        if total > 64:
            raise SdoAbortError(ABORT_PDO_LENGTH, f"{ObjRef(index, 0)}: {total} bits")
        return
    if int(values.get(index, 0, 0)) != 0:
        raise SdoAbortError(ABORT_STATE, f"{ObjRef(index, 0)} must be 0 while mapping")
    check_mapping_entry(values, int(value), require_mappable=require_mappable)
