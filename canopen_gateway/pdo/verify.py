"""``verify_mapping``: what to read back after configuring a node, and the comparison.

After the boot configuration the gateway uploads, for every PDO it decodes or encodes, the
COB-ID (180xh/140xh sub 01h) and the mapping (1A0xh/160xh sub 00h and the entries) and
compares them with the layout its codecs were compiled from (``canopen_gateway.profiles.layout``: one
result for the boot steps, the codecs and this check). A mismatch means the device would be
decoded with the wrong layout: the node's process values are marked bad, and the mismatch says
which PDO, what was expected and what the device holds.

How it is run: the master gives ``mapping_reads`` to the node's machine (``bus.node.node.Node``,
``verify=``), which queues them as SDO uploads (purpose "verify") once the node is configured
and started, and calls ``compare_mapping`` when the last answer is in. It is not a lifecycle
step: its outcome does not change the node's lifecycle (the node is started either way; only
its values are refused until a verification passes, from the boot-up on).

Pure: imports canopen_gateway.profiles (layout) and canopen_gateway.canopen.objref; no I/O.

Imports: canopen.cia301, canopen.objref, eds.pdos, profiles (layout).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from canopen_gateway.canopen.cia301 import COB_ID_INVALID, COB_ID_MASK_29BIT
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.pdos import decode_entry, entry_value
from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.profiles.layout import pdo_cob_id, pdo_objects

Kind = Literal["tpdo", "rpdo"]
_COB_MASK = COB_ID_MASK_29BIT  # CiA 301: bits 0..28 the identifier; bit 30 (no RTR) is not compared


@dataclass(frozen=True)
class MappingRead:
    """One SDO upload of the check and the value the codecs expect."""

    kind: Kind
    number: int
    object: ObjRef
    type: str  # uint8 (sub 00h count) or uint32 (COB-ID, entries)
    expected: int
    what: Literal["cob_id", "count", "entry"]


@dataclass(frozen=True)
class MappingMismatch:
    kind: Kind
    number: int
    expected: str
    held: str

    def __str__(self) -> str:
        return f"{self.kind.upper()}{self.number}: expected {self.expected}, device holds {self.held}"


def mapping_reads(lp: LoadedProfile, node_id: int, variant: int | None = None) -> list[MappingRead]:
    """The uploads that check the node's layout, PDO by PDO (COB-ID, count, entries)."""
    tpdos, rpdos = lp.profile.layout(variant if lp.profile.pdo_variants else None)
    out: list[MappingRead] = []
    for kind, pdos in (("tpdo", tpdos), ("rpdo", rpdos)):
        k: Kind = kind  # type: ignore[assignment]
        for p in pdos:
            comm, mapping = pdo_objects(lp.profile, k, p.number)
            out.append(MappingRead(k, p.number, ObjRef(comm, 1), "uint32", pdo_cob_id(k, p, node_id), "cob_id"))  # fmt: skip
            out.append(MappingRead(k, p.number, ObjRef(mapping, 0), "uint8", len(p.mapping), "count"))
            for i, e in enumerate(p.mapping, start=1):
                out.append(
                    MappingRead(k, p.number, ObjRef(mapping, i), "uint32", entry_value(e.object, e.bits), "entry")  # fmt: skip
                )
    return out


def _layout_text(cob: int | None, entries: list[int | None]) -> str:
    def cob_text(v: int | None) -> str:
        if v is None:
            return "COB-ID (no answer)"
        return f"COB-ID 0x{v & _COB_MASK:03X}" + (" (not valid)" if v & COB_ID_INVALID else "")

    def entry_text(v: int | None) -> str:
        if v is None:
            return "?"
        obj, bits = decode_entry(v)
        return f"{obj}/{bits}"

    return f"{cob_text(cob)}, [{', '.join(entry_text(v) for v in entries)}]"


def compare_mapping(
    reads: list[MappingRead], held: Mapping[ObjRef, int | None]
) -> list[MappingMismatch]:
    """Mismatches per PDO between the expected layout and the uploaded values (None = the
    upload failed: counted as a mismatch, the layout cannot be trusted)."""
    out: list[MappingMismatch] = []
    groups: dict[tuple[Kind, int], list[MappingRead]] = {}
    for r in reads:
        groups.setdefault((r.kind, r.number), []).append(r)
    for (kind, number), rs in groups.items():
        cob_r = next(r for r in rs if r.what == "cob_id")
        count_r = next(r for r in rs if r.what == "count")
        entries = [r for r in rs if r.what == "entry"]
        cob = held.get(cob_r.object)
        count = held.get(count_r.object)
        ok = cob is not None and (cob & (_COB_MASK | COB_ID_INVALID)) == cob_r.expected
        ok = ok and count == count_r.expected
        held_entries = [held.get(r.object) for r in entries]
        ok = ok and all(h == r.expected for h, r in zip(held_entries, entries, strict=True))
        if ok:
            continue
        n_held = count if count is not None else len(entries)
        shown = held_entries[: n_held] if n_held <= len(entries) else held_entries
        out.append(
            MappingMismatch(
                kind,
                number,
                _layout_text(cob_r.expected, [r.expected for r in entries]),
                _layout_text(cob, shown) + (f" ({count} entries)" if count is not None and count != len(entries) else ""),
            )
        )
    return out
