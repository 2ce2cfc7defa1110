"""Precompiled PDO codecs: a node's PDO mapping turned once into ``struct`` formats.

The per-frame path is ``TpdoCodec.decode(data)``: one ``Struct.unpack_from`` for byte-aligned
mappings (all of the manuals' default layouts), a bit-slicing fallback otherwise. Mapped objects
without a profile signal (dummies such as AP05 5F1Dh, DS-301 dummy types 0002h..0007h) are
decoded and dropped.

Which mapping: the profile's layout (or the chosen ``pdo_variants`` layout), then every SDO
write of the node's boot configuration to a PDO's communication (COB-ID, 1400h/1800h sub 01h)
or mapping object (1600h/1A00h) applied in order, as the device applies them. So a remap given
as node ``sdo:`` writes (MSK5000 manual 4.3.1.2) is decoded exactly as the device will send it,
without reading 1A0xh back (a read-back would be wrong for devices whose mapping objects do not
show the layout in use, such as the POSI+ with its PDO type object 2005h, manual 002 5).

Imports: profiles (schema), objref. Nothing northbound.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from gateway.objref import ObjRef
from gateway.profiles import LoadedProfile
from gateway.profiles.schema import Pdo, PdoEntry, Signal, default_cob_id

# struct codes by (bits, signed)
_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h", (32, False): "I",
          (32, True): "i", (64, False): "Q", (64, True): "q"}  # fmt: skip

_SIGNED_OD = {0x0002, 0x0003, 0x0004, 0x0010, 0x0015}  # INTEGER8/16/32/24/64 (DS-301 table 44)
_REAL32 = 0x0008


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
        t = sig.type
        return t.startswith("int"), t == "float32", t in ("string", "bytes")
    if obj.index < 0x1000:  # a DS-301 dummy data type entry
        return obj.index in _SIGNED_OD, obj.index == _REAL32, False
    var = lp.od_var(obj)
    dt = var.data_type if var is not None else 0
    return dt in _SIGNED_OD, dt == _REAL32, dt in (0x0009, 0x000A)


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
        elif f.is_float and f.bits == 32:
            fmt += "f"
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
                out.append(struct.unpack("<f", raw.to_bytes(4, "little"))[0])
            elif f.signed and raw >> (f.bits - 1):
                out.append(raw - (1 << f.bits))
            else:
                out.append(raw)
        return tuple(out)


class RpdoCodec:
    """Encodes one RPDO from the values of its mapped fields (stateless: the values are the
    node's output image, owned by ``bus.node.Node``)."""

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
                raw = int.from_bytes(struct.pack("<f", v), "little")
            else:
                raw = int(v) & ((1 << f.bits) - 1)
            word |= raw << f.bit_offset
        return word.to_bytes(self.length, "little")


def pdo_cob_id(kind: str, pdo: Pdo, node_id: int) -> int:
    base = pdo.cob_id if pdo.cob_id is not None else default_cob_id(kind, pdo.number)  # type: ignore[arg-type]
    return base + node_id if pdo.add_node_id else base


#: DS-301: COB-ID bit 31 = PDO not valid (MSK5000 manual 4.3.1.2 step 2); bits 0..10 the CAN-ID.
COB_ID_INVALID = 0x80000000
COB_ID_MASK_11BIT = 0x7FF


class PdoMappingError(ValueError):
    """The boot writes leave a PDO with a mapping the gateway cannot decode."""


def pdo_objects(lp: LoadedProfile, kind: Literal["tpdo", "rpdo"], number: int) -> tuple[int, int]:
    """(communication index, mapping index) of PDO ``number``: DS-301 1400h/1600h (RPDO),
    1800h/1A00h (TPDO) + number - 1, or what the ``remappable_tpdo`` feature names."""
    if kind == "tpdo":
        spec = (lp.profile.features.get("remappable_tpdo") or {}).get("tpdos") or {}
        objs = spec.get(number) or spec.get(str(number)) or {}
        comm = ObjRef.parse(objs.get("communication", 0x1800 + number - 1)).index
        mapping = ObjRef.parse(objs.get("mapping", 0x1A00 + number - 1)).index
        return comm, mapping
    return 0x1400 + number - 1, 0x1600 + number - 1


def _pdo_index_lookup(
    lp: LoadedProfile, kind: Literal["tpdo", "rpdo"]
) -> tuple[Callable[[int], int | None], Callable[[int], int | None]]:
    """Functions index -> PDO number for communication and mapping objects (DS-301 ranges
    1400h-15FFh / 1600h-17FFh for RPDOs, 1800h-19FFh / 1A00h-1BFFh for TPDOs, unless the
    ``remappable_tpdo`` feature names other objects)."""
    comm_base, map_base = (0x1800, 0x1A00) if kind == "tpdo" else (0x1400, 0x1600)
    comm_named: dict[int, int] = {}
    map_named: dict[int, int] = {}
    if kind == "tpdo":
        spec = (lp.profile.features.get("remappable_tpdo") or {}).get("tpdos") or {}
        for n in spec:
            comm_named[pdo_objects(lp, kind, int(n))[0]] = int(n)
            map_named[pdo_objects(lp, kind, int(n))[1]] = int(n)

    def lookup(named: dict[int, int], base: int) -> Callable[[int], int | None]:
        def number(index: int) -> int | None:
            if index in named:
                return named[index]
            return index - base + 1 if base <= index < base + 0x200 else None

        return number

    return lookup(comm_named, comm_base), lookup(map_named, map_base)


def _entry_value(e: PdoEntry) -> int:
    """DS-301 mapping entry: index << 16 | sub << 8 | length in bits (MSK5000 manual 4.3.1.2)."""
    return (e.object.index << 16) | (e.object.sub << 8) | e.bits


def apply_pdo_writes(
    lp: LoadedProfile,
    kind: Literal["tpdo", "rpdo"],
    pdos: Sequence[Pdo],
    node_id: int,
    writes: Iterable[tuple[ObjRef, Any]],
) -> list[Pdo]:
    """The PDOs as the device has them after ``writes`` (SDO downloads, in order).

    Starts from ``pdos`` (the profile layout) and replays the writes to each PDO's COB-ID
    (sub 01h) and mapping (sub 00h = number of entries, 01h.. = entries). A PDO left with
    COB-ID bit 31 set or no entries is dropped (the device does not send it); a PDO number
    outside the layout is added when the writes give it both a valid COB-ID and a mapping.
    Raises PdoMappingError for a mapping longer than 8 bytes.
    """
    state: dict[int, dict[str, Any]] = {}
    for p in pdos:
        entries = {i: _entry_value(e) for i, e in enumerate(p.mapping, start=1)}
        state[p.number] = {
            "pdo": p,
            "cob": pdo_cob_id(kind, p, node_id),
            "count": len(p.mapping),
            "entries": entries,
            "cob_written": False,
            "map_written": False,
        }
    by_comm, by_map = _pdo_index_lookup(lp, kind)
    for obj, value in writes:
        number = by_comm(obj.index) if obj.sub == 0x01 else None
        is_map = False
        if number is None:
            number = by_map(obj.index)
            is_map = number is not None
        if number is None:
            continue
        st = state.setdefault(
            number,
            {"pdo": None, "cob": COB_ID_INVALID, "count": 0, "entries": {},
             "cob_written": False, "map_written": False},
        )  # fmt: skip
        v = int(value)
        if not is_map:
            st["cob"] = v
            st["cob_written"] = True
        elif obj.sub == 0:
            st["count"] = v
            st["map_written"] = True
        else:
            st["entries"][obj.sub] = v
            st["map_written"] = True
    out: list[Pdo] = []
    for number in sorted(state):
        st = state[number]
        base: Pdo | None = st["pdo"]
        if base is None and not (st["cob_written"] and st["map_written"]):
            continue
        if st["cob"] & COB_ID_INVALID or st["count"] == 0:
            continue
        if base is not None and not st["cob_written"] and not st["map_written"]:
            out.append(base)
            continue
        mapping = []
        for i in range(1, st["count"] + 1):
            raw = st["entries"].get(i)
            if raw is None:
                raise PdoMappingError(
                    f"{kind.upper()}{number}: mapping sub-index {i} is enabled but never written"
                )
            mapping.append({"object": ObjRef(raw >> 16, (raw >> 8) & 0xFF), "bits": raw & 0xFF})
        fields: dict[str, Any] = {
            "number": number,
            "cob_id": st["cob"] & COB_ID_MASK_11BIT,
            "add_node_id": False,
            "mapping": mapping,
        }
        if base is not None:
            fields.update(
                transmission_type=base.transmission_type,
                event_timer_ms=base.event_timer_ms,
                inhibit_time_100us=base.inhibit_time_100us,
                description=base.description,
            )
        try:
            out.append(Pdo.model_validate(fields))
        except ValueError as exc:
            raise PdoMappingError(f"{kind.upper()}{number}: {exc}") from None
    return out


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
