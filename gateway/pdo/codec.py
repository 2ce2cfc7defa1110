"""Precompiled PDO codecs: a node's PDO mapping turned once into ``struct`` formats.

The per-frame path is ``TpdoCodec.decode(data)``: one ``Struct.unpack_from`` for byte-aligned
mappings (all of the manuals' default layouts), a bit-slicing fallback otherwise. Mapped objects
without a profile signal (dummies such as AP05 5F1Dh, DS-301 dummy types 0002h..0007h) are
decoded and dropped.

Which mapping: the node's layout as ``gateway.profiles.load_node_profile`` resolved it (profile
or EDS layout, the node's ``tpdo:``/``rpdo:`` settings, its PDO writes replayed in order; see
``gateway.profiles.layout``), the one result the boot-step builder also writes from. Writes
given here are replayed on top once more (idempotent for the node's own boot steps). So a remap
(MSK5000 manual 4.3.1.2) is decoded exactly as the device will send it, without trusting a
read-back alone (wrong for devices whose mapping objects do not show the layout in use, such
as the POSI+ with its PDO type object 2005h, manual 002 5; ``verify_mapping`` compares where
the mapping objects do describe it).

Imports: cia301, profiles (schema), objref. Nothing northbound.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from gateway.cia301 import (
    OCTET_STRING,
    REAL32,
    REAL64,
    SIGNED_TYPES,
    VISIBLE_STRING,
)
from gateway.objref import ObjRef
from gateway.profiles import LoadedProfile
from gateway.profiles.layout import PdoMappingError, pdo_cob_id
from gateway.profiles.layout import apply_pdo_writes as _apply_pdo_writes
from gateway.profiles.layout import pdo_objects as _pdo_objects
from gateway.profiles.schema import Pdo, Signal

__all__ = ["PdoMappingError", "RpdoCodec", "TpdoCodec", "apply_pdo_writes", "compile_node",
           "pdo_cob_id", "pdo_objects"]  # fmt: skip

# struct codes by (bits, signed)
_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h", (32, False): "I",
          (32, True): "i", (64, False): "Q", (64, True): "q"}  # fmt: skip
# struct codes of the IEEE 754 types by bits (CiA 301 7.1.4.4: REAL32, REAL64)
_FLOAT_CODES = {32: "f", 64: "d"}
_FLOAT_TYPES = {"float32": REAL32, "float64": REAL64}



@dataclass(frozen=True)
class Field:
    obj: ObjRef
    bits: int
    bit_offset: int
    signal: str | None  # None = dummy / unnamed
    signed: bool
    is_float: bool
    is_text: bool


def _field_kind(lp: LoadedProfile, obj: ObjRef, sig: Signal | None) -> tuple[bool, bool, bool]:
    if sig is not None:
        t = sig.type_name
        return t.startswith("int"), t in _FLOAT_TYPES, t in ("string", "bytes")
    if obj.index < 0x1000:  # a DS-301 dummy data type entry
        return obj.index in SIGNED_TYPES, obj.index in _FLOAT_TYPES.values(), False
    var = lp.od_var(obj)
    dt = var.data_type if var is not None else 0
    return dt in SIGNED_TYPES, dt in _FLOAT_TYPES.values(), dt in (VISIBLE_STRING, OCTET_STRING)


def compile_fields(lp: LoadedProfile, pdo: Pdo) -> list[Field]:
    out = []
    offset = 0
    for e in pdo.mapping:
        sig = lp.profile.signal_for(e.object)
        signed, is_float, is_text = _field_kind(lp, e.object, sig)
        out.append(
            Field(e.object, e.bits, offset, sig.name if sig else None, signed, is_float, is_text)
        )
        offset += e.bits
    return out


def _struct_format(fields: Sequence[Field]) -> str | None:
    fmt = "<"
    for f in fields:
        if f.bit_offset % 8:
            return None
        if f.is_text:
            fmt += f"{f.bits // 8}s"
        elif f.is_float and f.bits in _FLOAT_CODES:
            fmt += _FLOAT_CODES[f.bits]
        elif (f.bits, f.signed) in _CODES:
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
        out: list[Any] = []
        for f in self.fields:
            raw = (word >> f.bit_offset) & ((1 << f.bits) - 1)
            if f.is_text:
                out.append(raw.to_bytes(f.bits // 8, "little"))
            elif f.is_float:
                code = _FLOAT_CODES.get(f.bits, "f")
                out.append(struct.unpack("<" + code, raw.to_bytes(struct.calcsize(code), "little"))[0])
            elif f.signed and raw >> (f.bits - 1):
                out.append(raw - (1 << f.bits))
            else:
                out.append(raw)
        return tuple(out)


class RpdoCodec:
    """Encodes one RPDO from the values of its mapped fields (stateless: the values are the
    node's output image, owned by ``bus.node.owner.Node``)."""

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

    def encode(self, values: Sequence[Any]) -> bytes:
        if self._pack is not None:
            return self._pack(*values)
        word = 0
        for f, v in zip(self.fields, values, strict=True):
            if f.is_text:
                raw = int.from_bytes(v, "little")
            elif f.is_float:
                raw = int.from_bytes(struct.pack("<" + _FLOAT_CODES.get(f.bits, "f"), v), "little")
            else:
                raw = int(v) & ((1 << f.bits) - 1)
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
