"""The PDOs an EDS describes, and signal names and types derived from its dictionary.

CiA 301 7.5.2.35-7.5.2.38: RPDO *n* has its communication parameter at 1400h + n - 1 and its
mapping at 1600h + n - 1, TPDO *n* at 1800h / 1A00h + n - 1. Communication sub 01h is the
COB-ID (bit 31 = PDO not valid, ``$NODEID`` resolved for the node), 02h the transmission type,
03h the inhibit time (100 us), 05h the event timer (ms), 06h the SYNC start value. Mapping
sub 00h is the number of entries, each entry ``index << 16 | sub << 8 | bits``.

Names: the ParameterName of the object (of the sub-object for ARRAY/RECORD entries, prefixed by
the object's name when the sub-object's name alone says little) as a snake_case slug; slugs
that two objects of a node share, or that are empty, fall back to ``<slug>_<index>_<sub>``.

Imports: canopen (dictionary types), canopen_gateway.canopen.cia301 (COB-ID bits, PDO indices, data types),
canopen_gateway.canopen.objref, canopen_gateway.eds.parse.
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from typing import Any, Literal

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

from canopen_gateway.canopen.cia301 import (
    COB_ID_INVALID,
    PDO_COMM_BASE,
    PDO_MAP_BASE,
    REAL32,
    REAL64,
    SIGNED_TYPES,
    TYPE_BITS,
    TYPE_NAMES,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.parse import DATA_TYPES

Kind = Literal["tpdo", "rpdo"]

#: CiA 301 7.5.2.36: a mapping object has at most 64 entries (sub 01h..40h).
MAX_ENTRIES = 0x40
#: the PDO facts of CiA 301, named here for the modules that read PDOs from an EDS
COMM_BASE = PDO_COMM_BASE
MAP_BASE = PDO_MAP_BASE
#: the float types (CiA 301 7.4.7.1 table 44): mapped with another length than theirs they have no value
FLOAT_TYPES = (REAL32, REAL64)
_NODEID_RE = re.compile(r"\$NODEID", re.IGNORECASE)


def od_var(od: canopen.ObjectDictionary, obj: ObjRef) -> ODVariable | None:
    try:
        entry = od[obj.index]
    except KeyError:
        return None
    if isinstance(entry, ODVariable):
        return entry if obj.sub == 0 else None
    if obj.sub not in entry.subindices:
        return None  # canopen makes up array sub-objects on access; the EDS has not this one
    try:
        return entry[obj.sub]
    except KeyError:
        return None


def default_value(var: ODVariable | None, node_id: int | None) -> Any:
    """The EDS default (a DCF's ParameterValue first) with ``$NODEID`` resolved; None if none."""
    if var is None:
        return None
    raw = getattr(var, "value_raw", None) or getattr(var, "default_raw", None)
    if isinstance(raw, str) and _NODEID_RE.search(raw):
        total = 0
        for term in _NODEID_RE.sub(str(node_id or 0), raw.replace(" ", "")).split("+"):
            if term:
                total += int(term, 0)
        return total
    value = getattr(var, "value", None)
    return value if value is not None else var.default


def entry_value(obj: ObjRef, bits: int) -> int:
    """CiA 301 mapping entry: index << 16 | sub << 8 | length in bits."""
    return (obj.index << 16) | (obj.sub << 8) | bits


def decode_entry(raw: int) -> tuple[ObjRef, int]:
    return ObjRef((raw >> 16) & 0xFFFF, (raw >> 8) & 0xFF), raw & 0xFF


def object_bits(od: canopen.ObjectDictionary, obj: ObjRef) -> int | None:
    """Bit length of a mappable object (a dummy data type entry 0001h..0007h too); None for
    strings and unknown objects."""
    if obj.index < 0x1000:
        return TYPE_BITS.get(obj.index)
    var = od_var(od, obj)
    if var is None:
        return None
    return TYPE_BITS.get(var.data_type)


@dataclass(frozen=True)
class EdsPdo:
    """One PDO as the EDS (or DCF) describes it, for one node id."""

    kind: Kind
    number: int
    comm_index: int
    map_index: int
    cob_id: int  # as held, bit 31 = not valid
    transmission_type: int | None
    inhibit_time_100us: int | None
    event_timer_ms: int | None
    sync_start: int | None
    entries: tuple[tuple[ObjRef, int], ...]
    mapping_writable: bool
    comm_writable: bool
    count: int = 0  # mapping sub 00h as the file gives it
    gaps: tuple[int, ...] = ()  # mapping sub-indices 01h..count without a value in the file

    @property
    def enabled(self) -> bool:
        return not self.cob_id & COB_ID_INVALID and bool(self.entries)

    @property
    def bits(self) -> int:
        return sum(b for _, b in self.entries)


def _as_int(v: Any, top: int | None = None) -> int | None:
    """An integer value of the file (None for text, bytes, floats or out of ``0..top``)."""
    if isinstance(v, bool) or not isinstance(v, int):
        return None
    if v < 0 or (top is not None and v > top):
        return None
    return v


def _writable(var: ODVariable | None) -> bool:
    return var is not None and var.access_type in ("rw", "wo", "rww", "rwr")


def eds_pdos(od: canopen.ObjectDictionary, node_id: int | None, kind: Kind) -> list[EdsPdo]:
    """Every PDO of ``kind`` whose communication parameter is in the dictionary."""
    out = []
    base = COMM_BASE[kind]
    for index in sorted(i for i in od.indices if base <= i < base + 0x200):
        number = index - base + 1
        map_index = MAP_BASE[kind] + number - 1

        def comm(sub: int, index: int = index) -> Any:
            return default_value(od_var(od, ObjRef(index, sub)), node_id)

        cob = _as_int(comm(1))
        entries: list[tuple[ObjRef, int]] = []
        gaps: list[int] = []
        count = _as_int(default_value(od_var(od, ObjRef(map_index, 0)), node_id)) or 0
        for s in range(1, min(count, MAX_ENTRIES) + 1):
            raw = _as_int(default_value(od_var(od, ObjRef(map_index, s)), node_id))
            if raw:
                entries.append(decode_entry(raw))
            else:
                gaps.append(s)
        out.append(
            EdsPdo(
                kind=kind,
                number=number,
                comm_index=index,
                map_index=map_index,
                cob_id=cob if cob is not None else COB_ID_INVALID,
                transmission_type=_as_int(comm(2), 0xFF),
                inhibit_time_100us=_as_int(comm(3), 0xFFFF) if kind == "tpdo" else None,
                event_timer_ms=_as_int(comm(5), 0xFFFF),
                sync_start=_as_int(comm(6), 0xF0) if kind == "tpdo" else None,
                entries=tuple(entries),
                count=count,
                gaps=tuple(gaps),
                mapping_writable=_writable(od_var(od, ObjRef(map_index, 0))),
                comm_writable=_writable(od_var(od, ObjRef(index, 1))),
            )
        )
    return out


# ------------------------------------------------------------------------ names


def slug(text: str) -> str:
    """``"Read Input 8-Bit (1h..8h)"`` -> ``read_input_8_bit_1h_8h``; ASCII, snake_case."""
    ascii_text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()
    s = re.sub(r"[^a-z0-9]+", "_", ascii_text.lower()).strip("_")
    if s and not s[0].isalpha():
        s = f"o_{s}"
    return s


_GENERIC_SUB = re.compile(r"^(sub[- _]?index|sub|entry|value|channel|input|output)?[ _-]*\d+h?$", re.I)


def object_name(od: canopen.ObjectDictionary, obj: ObjRef) -> str:
    """ParameterName of the object; for a sub-object its own name, prefixed with the object's
    name when the sub-object's name is only a number or a generic word and number."""
    entry = od.get(obj.index)
    if entry is None:
        return ""
    if isinstance(entry, ODVariable):
        return entry.name
    var = od_var(od, obj)
    sub_name = var.name if var is not None else ""
    if isinstance(entry, (ODArray, ODRecord)) and (not sub_name or _GENERIC_SUB.match(sub_name)):
        return f"{entry.name} {sub_name or obj.sub}"
    return sub_name


def unique_names(od: canopen.ObjectDictionary, objs: list[ObjRef], taken: set[str]) -> dict[ObjRef, str]:
    """A signal name per object: its slug; shared or empty slugs (also with ``taken`` names of
    the profile) get ``_<index>_<sub>`` appended."""
    slugs = {o: slug(object_name(od, o)) for o in objs}
    counts: dict[str, int] = {}
    for s in slugs.values():
        counts[s] = counts.get(s, 0) + 1
    out: dict[ObjRef, str] = {}
    for o, s in slugs.items():
        if not s:
            out[o] = f"obj_{o.index:04x}_{o.sub:02x}"
        elif counts[s] > 1 or s in taken:
            out[o] = f"{s}_{o.index:04x}_{o.sub:02x}"
        else:
            out[o] = s
    return out


def signal_type(var: ODVariable | None) -> str | None:
    return TYPE_NAMES.get(var.data_type) if var is not None else None


def access_of(var: ODVariable | None) -> Literal["ro", "rw", "wo"]:
    if var is None:
        return "ro"
    a = var.access_type
    if a in ("rw", "rww", "rwr"):
        return "rw"
    if a == "wo":
        return "wo"
    return "ro"


def readable(var: ODVariable | None) -> bool:
    return var is not None and var.access_type in ("ro", "rw", "rwr", "rww", "const")


def mappable_objects(od: canopen.ObjectDictionary, kind: Kind) -> list[ObjRef]:
    """The objects of the dictionary the file marks PDO-mappable (``PDOMapping=1``) of a type
    the gateway serves, readable for a TPDO or writable for an RPDO, in index order (the
    objects ``tpdo:`` / ``rpdo:`` of a node entry may map)."""
    out = []
    for index in sorted(od.indices):
        entry = od[index]
        if isinstance(entry, ODVariable):
            subs = [(0, entry)]
        else:
            subs = [(sub, entry[sub]) for sub in sorted(entry.subindices) if sub]
        for sub, var in subs:
            if not var.pdo_mappable or TYPE_NAMES.get(var.data_type) is None:
                continue
            if readable(var) if kind == "tpdo" else _writable(var):
                out.append(ObjRef(index, sub))
    return out


# ------------------------------------------------------------------------ what a PDO can carry


@dataclass(frozen=True)
class PdoFinding:
    """A problem of one mapping entry of one PDO: ``fatal`` when the gateway would decode the
    PDO wrongly (the node is refused), else a warning (the entry is decoded and dropped, or
    an integer served at the narrower of its mapped and its type's length)."""

    fatal: bool
    pdo: str  # "TPDO4"
    obj: ObjRef  # the mapping sub-object (1A03h:02), or the mapping object (1A03h:00)
    message: str


def mapping_findings(
    od: canopen.ObjectDictionary,
    kind: Kind,
    number: int,
    map_index: int,
    entries: tuple[tuple[ObjRef, int], ...] | list[tuple[ObjRef, int]],
    gaps: tuple[int, ...] = (),
    count: int | None = None,
) -> list[PdoFinding]:
    """What the gateway can and cannot do with one enabled PDO mapping (CiA 301 7.5.2.36/38).

    Fatal (the offsets or the frame length would be wrong): more than 64 entries, an entry
    counted in sub 00h without a value, an entry naming an index below 1000h that is not a
    dummy data type, a zero length, more than 64 bits in all. Warnings (the entry is decoded at
    its offset by the length the mapping gives): an object the dictionary does not define or of
    a type the gateway does not serve (DOMAIN, UNICODE_STRING) is
    skipped; a float (REAL32/REAL64) mapped with a length other than its type's is skipped
    (it has no value); an integer mapped narrower than its type is served at the mapped width
    (its writes limited to it), wider from the low bits of the type's width; an object marked
    not PDO-mappable, not readable (TPDO) or not writable (RPDO)."""
    pdo = f"{kind.upper()}{number}"
    out: list[PdoFinding] = []
    if count is not None and count > MAX_ENTRIES:
        out.append(PdoFinding(True, pdo, ObjRef(map_index, 0), f"{pdo}: {map_index:04X}h:00 = {count} entries; a mapping has at most 64"))  # fmt: skip
    for sub in gaps:
        out.append(PdoFinding(True, pdo, ObjRef(map_index, sub), f"{pdo}: {map_index:04X}h:00 counts entry {sub:02X}h, which has no value"))  # fmt: skip
    total = 0
    for i, (obj, bits) in enumerate(entries, start=1):
        at = ObjRef(map_index, i)
        total += bits
        if bits == 0:
            out.append(PdoFinding(True, pdo, at, f"{pdo} entry {obj}/0: a length of 0 bits"))
            continue
        if obj.index < 0x1000:
            if obj.index not in TYPE_BITS:
                out.append(PdoFinding(True, pdo, at, f"{pdo} maps {obj}: not a dummy data type (0001h..0007h and the like)"))  # fmt: skip
            continue
        var = od_var(od, obj)
        if var is None:
            what = f"{obj.index:04X}h has no sub-index {obj.sub:02X}h" if obj.index in od else "the file does not define it"  # fmt: skip
            out.append(PdoFinding(False, pdo, at, f"{pdo} maps {obj}/{bits}, but {what}: its type is unknown, so it is skipped; the other signals of {pdo} are served"))  # fmt: skip
            continue
        type_name = DATA_TYPES.get(var.data_type or 0, f"0x{var.data_type or 0:04X}")
        served = signal_type(var)
        if served is None:
            out.append(PdoFinding(False, pdo, at, f"{pdo} entry {obj}/{bits} ({type_name}) is not a type the gateway serves: skipped, the other signals of {pdo} are served"))  # fmt: skip
            continue
        want = TYPE_BITS.get(var.data_type)
        if want is not None and want != bits:
            head = f"{pdo} entry {obj}/{bits}: the object is {type_name} ({want} bit)"
            if var.data_type in FLOAT_TYPES:
                out.append(PdoFinding(False, pdo, at, f"{head}; a float of another length has no value: skipped, the other signals of {pdo} are served"))  # fmt: skip
                continue
            if bits < want:
                sign = ", sign-extended" if var.data_type in SIGNED_TYPES else ""
                limit = "; writes are limited to that width" if kind == "rpdo" else ""
                out.append(PdoFinding(False, pdo, at, f"{head}; served at the {bits} bits the device sends{sign}{limit}"))  # fmt: skip
            else:
                out.append(PdoFinding(False, pdo, at, f"{head}; served from the low {want} of the {bits} bits"))  # fmt: skip
        if served in ("string", "bytes") and bits % 8:
            out.append(PdoFinding(False, pdo, at, f"{pdo} entry {obj}/{bits}: a {type_name} of whole bytes; the last {bits % 8} bits are dropped"))  # fmt: skip
        if not var.pdo_mappable:
            out.append(PdoFinding(False, pdo, at, f"{pdo} entry {obj}: PDOMapping=0 in the file"))
        if kind == "tpdo" and not readable(var):
            out.append(PdoFinding(False, pdo, at, f"{pdo} entry {obj}: not readable ({var.access_type}) in the file"))  # fmt: skip
        if kind == "rpdo" and var.access_type not in ("rw", "wo", "rww", "rwr"):
            out.append(PdoFinding(False, pdo, at, f"{pdo} entry {obj}: not writable ({var.access_type}) in the file"))  # fmt: skip
    if total > 64:
        out.append(PdoFinding(True, pdo, ObjRef(map_index, 0), f"{pdo} maps {total} bits; a PDO carries at most 64"))  # fmt: skip
    return out


def eds_pdo_findings(od: canopen.ObjectDictionary, node_id: int | None = None) -> list[PdoFinding]:
    """``mapping_findings`` of every enabled PDO the file describes."""
    out: list[PdoFinding] = []
    for kind in ("tpdo", "rpdo"):
        for p in eds_pdos(od, node_id, kind):
            if p.cob_id & COB_ID_INVALID or not (p.entries or p.gaps):
                continue
            out += mapping_findings(od, p.kind, p.number, p.map_index, p.entries, p.gaps, p.count)
    return out

