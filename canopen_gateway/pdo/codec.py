"""Precompiled PDO codecs: a node's PDO mapping turned once into ``struct`` formats.

The per-frame path is ``TpdoCodec.decode(data)``: one ``Struct.unpack_from`` for byte-aligned
mappings (all of the manuals' default layouts), a bit-slicing fallback otherwise. Mapped objects
without a profile signal (dummies such as AP05 5F1Dh, DS-301 dummy types 0002h..0007h) are
decoded and dropped.

Which mapping: the node's layout as ``canopen_gateway.profiles.load_node_profile`` resolved it (profile
or EDS layout, the node's ``tpdo:``/``rpdo:`` settings, its PDO writes replayed in order; see
``canopen_gateway.profiles.layout``), the one result the boot-step builder also writes from. Writes
given here are replayed on top once more (idempotent for the node's own boot steps). So a remap
(MSK5000 manual 4.3.1.2) is decoded exactly as the device will send it, without trusting a
read-back alone (wrong for devices whose mapping objects do not show the layout in use, such
as the POSI+ with its PDO type object 2005h, manual 002 5; ``verify_mapping`` compares where
the mapping objects do describe it).

Imports: canopen.cia301, profiles (schema), canopen.objref. Nothing northbound.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from canopen_gateway.canopen.cia301 import (
    OCTET_STRING,
    REAL32,
    REAL64,
    SIGNED_TYPES,
    VISIBLE_STRING,
)
from canopen_gateway.canopen.cia301 import TYPE_BITS as _CIA_TYPE_BITS
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.profiles.layout import PdoMappingError, pdo_cob_id
from canopen_gateway.profiles.layout import apply_pdo_writes as _apply_pdo_writes
from canopen_gateway.profiles.layout import pdo_objects as _pdo_objects
from canopen_gateway.profiles.schema import TYPE_BITS, Pdo, Signal

__all__ = ["FieldValueError", "PdoMappingError", "RpdoCodec", "TpdoCodec", "apply_pdo_writes", "compile_node",
           "pdo_cob_id", "pdo_objects"]  # fmt: skip

# struct codes by (bits, signed)
_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h", (32, False): "I",
          (32, True): "i", (64, False): "Q", (64, True): "q"}  # fmt: skip
# IEEE 754 struct codes by bits (REAL32, REAL64)
_FLOAT_CODES = {32: "f", 64: "d"}
_FLOAT_TYPES = (REAL32, REAL64)


@dataclass(frozen=True)
class Field:
    """One mapping entry: ``bits`` at ``bit_offset`` of the frame (CiA 301 7.5.2.36).

    ``type_bits`` is the width of the object's data type (None: text, or a type without a
    fixed width). An integer mapped with another length than its type's is carried at the
    narrower of the two (``value_bits``): a narrower entry is decoded at the mapped width (a
    signed type sign-extended from it) and its writes range-checked against that width; a
    wider one carries the type's value in its low bits. A float mapped with another length than
    its type's has no value: ``compile_fields`` makes it an unnamed raw field."""

    obj: ObjRef
    bits: int
    bit_offset: int
    signal: str | None  # None = dummy / unnamed
    signed: bool
    is_float: bool
    is_text: bool
    type_bits: int | None = None

    @property
    def value_bits(self) -> int:
        """The width the value is read and written at (see the class docstring)."""
        if self.type_bits is None or self.is_text or self.is_float:
            return self.bits
        return min(self.bits, self.type_bits)

    def value_range(self) -> tuple[int, int] | None:
        """The integers this field can carry (None for text and floats)."""
        if self.is_text or self.is_float:
            return None
        n = self.value_bits
        if self.signed:
            return -(1 << (n - 1)), (1 << (n - 1)) - 1
        return 0, (1 << n) - 1

    def raw(self, value: Any) -> int:
        """``value`` as the field's unsigned bits; raises FieldValueError when it does not fit."""
        if self.is_text:
            if not isinstance(value, (bytes, bytearray)):
                raise FieldValueError(self, value, "bytes")
            data = bytes(value)
            if len(data) > self.bits // 8:
                raise FieldValueError(self, value, f"at most {self.bits // 8} bytes")
            return int.from_bytes(data, "little")
        if self.is_float:
            try:
                packed = struct.pack("<" + _FLOAT_CODES[self.bits], float(value))
            except (OverflowError, TypeError, ValueError):
                raise FieldValueError(self, value, f"a number of REAL{self.bits}") from None
            return int.from_bytes(packed, "little")
        lo, hi = self.value_range()  # type: ignore[misc]
        if not isinstance(value, int) or not lo <= value <= hi:
            raise FieldValueError(self, value, f"an integer {lo}..{hi} ({self.value_bits} bits)")
        return value & ((1 << self.bits) - 1)  # a signed value sign-extended to the mapped width

    def value(self, raw: int) -> Any:
        """The field's unsigned bits ``raw`` as its value (the inverse of :meth:`raw`)."""
        if self.is_text:  # whole bytes: the bits of a last partial byte are dropped
            n = self.bits // 8
            return (raw & ((1 << 8 * n) - 1)).to_bytes(n, "little")
        if self.is_float:
            return struct.unpack("<" + _FLOAT_CODES[self.bits], raw.to_bytes(self.bits // 8, "little"))[0]
        n = self.value_bits
        raw &= (1 << n) - 1
        if self.signed and raw >> (n - 1):
            return raw - (1 << n)
        return raw


class FieldValueError(ValueError):
    """A value one field of an RPDO cannot carry (``allowed`` says what it can)."""

    def __init__(self, field: Field, value: Any, allowed: str):
        self.field, self.value, self.allowed = field, value, allowed
        super().__init__(f"{field.signal or field.obj}: value {value!r} not allowed, expected {allowed}")


def _field_kind(lp: LoadedProfile, obj: ObjRef, sig: Signal | None) -> tuple[bool, bool, bool, int | None]:
    """(signed, float, text, bits of the data type) of a mapped object."""
    if sig is not None:
        t = sig.type_name
        is_text = t in ("string", "bytes")
        return t.startswith("int"), t.startswith("float"), is_text, None if is_text else TYPE_BITS.get(t)
    var = lp.od_var(obj) if obj.index >= 0x1000 else None
    # a DS-301 dummy data type entry names its type by its index
    dt = obj.index if obj.index < 0x1000 else (var.data_type or 0) if var is not None else 0
    is_text = dt in (VISIBLE_STRING, OCTET_STRING)
    return dt in SIGNED_TYPES, dt in _FLOAT_TYPES, is_text, _CIA_TYPE_BITS.get(dt)


def compile_fields(lp: LoadedProfile, pdo: Pdo) -> list[Field]:
    """The fields of one PDO at their bit offsets. A float entry whose length is not its
    type's (a REAL32 mapped with 16 bits) has no value: it keeps its place as an unnamed raw
    field (decoded and dropped, sent as zeros), so the other entries keep their offsets."""
    out = []
    offset = 0
    for e in pdo.mapping:
        sig = lp.profile.signal_for(e.object)
        signed, is_float, is_text, type_bits = _field_kind(lp, e.object, sig)
        name = sig.name if sig else None
        if is_float and (e.bits != type_bits or e.bits not in _FLOAT_CODES):
            name, signed, is_float = None, False, False
        out.append(Field(e.object, e.bits, offset, name, signed, is_float, is_text, type_bits))
        offset += e.bits
    return out


def _struct_format(fields: Sequence[Field]) -> str | None:
    """One ``struct`` format for the whole frame, None when a field needs the bit path
    (unaligned, a width ``struct`` has no code for, an integer wider than its type, text of a
    partial byte)."""
    fmt = "<"
    for f in fields:
        if f.bit_offset % 8:
            return None
        if f.is_text:
            if f.bits % 8:
                return None
            fmt += f"{f.bits // 8}s"
        elif f.is_float:
            fmt += _FLOAT_CODES[f.bits]
        elif (f.bits, f.signed) in _CODES and f.value_bits == f.bits:
            fmt += _CODES[(f.bits, f.signed)]
        else:
            return None
    return fmt


class TpdoCodec:
    """Decodes one TPDO of one node into the values of its named signals."""

    __slots__ = ("cob_id", "number", "length", "fields", "names", "_unpack", "_keep", "_slow")

    def __init__(self, cob_id: int, number: int, fields: list[Field]):
        self.cob_id = cob_id
        self.number = number
        self.fields = fields
        self.length = (sum(f.bits for f in fields) + 7) // 8
        self.names: tuple[str, ...] = tuple(f.signal for f in fields if f.signal)
        keep = [i for i, f in enumerate(fields) if f.signal]
        fmt = _struct_format(fields)
        self._slow = fmt is None
        self._unpack = struct.Struct(fmt).unpack_from if fmt else None
        # when every field is named the tuple is returned as is (no re-packing per frame)
        self._keep: tuple[int, ...] | None = None if len(keep) == len(fields) else tuple(keep)

    def decode(self, data: bytes | bytearray) -> tuple[Any, ...]:
        """Values of ``self.names`` in order. Raises ValueError on a short frame."""
        if len(data) < self.length:
            raise ValueError(
                f"PDO 0x{self.cob_id:03X} has {len(data)} bytes, mapping needs {self.length}"
            )
        if self._slow:
            vals = self._decode_bits(data)
        else:
            vals = self._unpack(data)  # type: ignore[misc]
        if self._keep is None:
            return vals
        return tuple(vals[i] for i in self._keep)

    def _decode_bits(self, data: bytes | bytearray) -> tuple[Any, ...]:
        word = int.from_bytes(bytes(data[: self.length]), "little")
        return tuple(f.value((word >> f.bit_offset) & ((1 << f.bits) - 1)) for f in self.fields)


class RpdoCodec:
    """Encodes one RPDO from the values of its mapped fields (stateless: the values are the
    node's output image, owned by ``bus.node.node.Node``)."""

    __slots__ = ("cob_id", "number", "fields", "length", "names", "_pack", "_index")

    def __init__(self, cob_id: int, number: int, fields: list[Field]):
        self.cob_id = cob_id
        self.number = number
        self.fields = fields
        self.length = (sum(f.bits for f in fields) + 7) // 8
        self.names = tuple(f.signal for f in fields if f.signal)
        self._index = {f.signal: i for i, f in enumerate(fields) if f.signal}
        fmt = _struct_format(fields)
        self._pack = struct.Struct(fmt).pack if fmt else None

    def initial_values(self) -> list[Any]:
        """Zero (or NUL text) for every field, in mapping order."""
        return [b"\0" * (f.bits // 8) if f.is_text else 0 for f in self.fields]

    def index_of(self, signal: str) -> int | None:
        return self._index.get(signal)

    def field(self, signal: str) -> Field | None:
        """The mapping entry of ``signal`` in this RPDO (None: not mapped here)."""
        i = self._index.get(signal)
        return None if i is None else self.fields[i]

    def encode(self, values: Sequence[Any]) -> bytes:
        """The frame carrying ``values`` (one per field, mapping order). Raises
        FieldValueError, naming the field, for a value its mapped width cannot carry."""
        raws = [f.raw(v) for f, v in zip(self.fields, values, strict=True)]
        if self._pack is not None:
            return self._pack(*values)
        word = 0
        for f, raw in zip(self.fields, raws, strict=True):
            word |= raw << f.bit_offset
        return word.to_bytes(self.length, "little")


def pdo_objects(lp: LoadedProfile, kind: Literal["tpdo", "rpdo"], number: int) -> tuple[int, int]:
    """(communication index, mapping index) of PDO ``number`` (see profiles.layout)."""
    return _pdo_objects(lp.profile, kind, number)


def apply_pdo_writes(
    lp: LoadedProfile,
    kind: Literal["tpdo", "rpdo"],
    pdos: Sequence[Pdo],
    node_id: int,
    writes: Iterable[tuple[ObjRef, Any]],
) -> list[Pdo]:
    """The PDOs as the device has them after ``writes`` (see profiles.layout)."""
    return _apply_pdo_writes(lp.profile, kind, pdos, node_id, writes)


def compile_node(
    lp: LoadedProfile,
    node_id: int,
    variant: int | None = None,
    writes: Iterable[tuple[ObjRef, Any]] = (),
) -> tuple[list[TpdoCodec], list[RpdoCodec]]:
    """Codecs for a node's TPDOs and RPDOs: the profile layout (or the chosen variant) with the
    boot configuration's PDO writes applied (see :func:`apply_pdo_writes`)."""
    tpdos, rpdos = lp.profile.layout(variant)
    w = list(writes)
    if w:
        tpdos = apply_pdo_writes(lp, "tpdo", tpdos, node_id, w)
        rpdos = apply_pdo_writes(lp, "rpdo", rpdos, node_id, w)
    t = [TpdoCodec(pdo_cob_id("tpdo", p, node_id), p.number, compile_fields(lp, p)) for p in tpdos]
    r = [RpdoCodec(pdo_cob_id("rpdo", p, node_id), p.number, compile_fields(lp, p)) for p in rpdos]
    return t, r
