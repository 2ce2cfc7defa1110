"""PDO layouts: what the device holds after the boot configuration, derived in one place.

The layout of a node (its TPDOs and RPDOs, each a ``Pdo``) is, in this order:

1. the profile's ``tpdos``/``rpdos`` (or the chosen ``pdo_variants`` layout) when the profile
   gives them (devices whose mapping objects do not describe the layout: POSI+ 2005h, AP05);
   otherwise the enabled PDOs of the EDS (COB-ID bit 31 clear, ``$NODEID`` resolved);
2. the node's ``tpdo:``/``rpdo:`` settings, keyed by PDO number (``pdo_setting``);
3. the SDO writes of the boot configuration to PDO objects, replayed in order as the device
   applies them (``apply_pdo_writes``), e.g. a remap given as raw ``sdo:`` writes.

The boot-step builder (``canopen_gateway.device.boot_steps.build_boot_steps``) writes the CiA 301 sequence
of every PDO the node's settings name from this layout, the codecs (``canopen_gateway.pdo.codec``) are
compiled from it, ``verify_mapping`` compares the device with it, the register map and the
Zenoh keys serve its objects.

Imports: canopen_gateway.profiles.schema, canopen_gateway.profiles.node_setup, canopen_gateway.eds.pdos, canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref. No I/O.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, Literal

from pydantic import ValidationError

from canopen_gateway.canopen.cia301 import COB_ID_INVALID, COB_ID_MASK_11BIT
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.pdos import (
    EdsPdo,
    decode_entry,
    entry_value,
    object_bits,
    od_var,
)
from canopen_gateway.profiles.node_setup import PdoSetup
from canopen_gateway.profiles.schema import Pdo, PdoEntry, Profile, default_cob_id

Kind = Literal["tpdo", "rpdo"]


class PdoMappingError(ValueError):
    """The configuration leaves a PDO with a mapping the gateway cannot decode."""


def pdo_cob_id(kind: str, pdo: Pdo, node_id: int) -> int:
    base = pdo.cob_id if pdo.cob_id is not None else default_cob_id(kind, pdo.number)  # type: ignore[arg-type]
    return base + node_id if pdo.add_node_id else base


def pdo_objects(profile: Profile, kind: Kind, number: int) -> tuple[int, int]:
    """(communication index, mapping index) of PDO ``number``: CiA 301 1400h/1600h (RPDO),
    1800h/1A00h (TPDO) + number - 1, or what the ``remappable_tpdo`` feature names."""
    if kind == "tpdo":
        spec = (profile.features.get("remappable_tpdo") or {}).get("tpdos") or {}
        objs = spec.get(number) or spec.get(str(number)) or {}
        comm = ObjRef.parse(objs.get("communication", 0x1800 + number - 1)).index
        mapping = ObjRef.parse(objs.get("mapping", 0x1A00 + number - 1)).index
        return comm, mapping
    return 0x1400 + number - 1, 0x1600 + number - 1


def _pdo_index_lookup(
    profile: Profile, kind: Kind
) -> tuple[Callable[[int], int | None], Callable[[int], int | None]]:
    """Functions index -> PDO number for communication and mapping objects."""
    comm_base, map_base = (0x1800, 0x1A00) if kind == "tpdo" else (0x1400, 0x1600)
    comm_named: dict[int, int] = {}
    map_named: dict[int, int] = {}
    if kind == "tpdo":
        spec = (profile.features.get("remappable_tpdo") or {}).get("tpdos") or {}
        for n in spec:
            comm_named[pdo_objects(profile, kind, int(n))[0]] = int(n)
            map_named[pdo_objects(profile, kind, int(n))[1]] = int(n)

    def lookup(named: dict[int, int], base: int) -> Callable[[int], int | None]:
        def number(index: int) -> int | None:
            if index in named:
                return named[index]
            return index - base + 1 if base <= index < base + 0x200 else None

        return number

    return lookup(comm_named, comm_base), lookup(map_named, map_base)


def tpdo_objects(profile: Profile, variant: int | None = None) -> frozenset[ObjRef]:
    """Objects the TPDOs of the layout carry: the node's inputs. A signal whose object is here
    is served as an input (the device's value), also when an RPDO carries it too (then it is
    an output as well, e.g. a command number the device echoes)."""
    tpdos, _ = profile.layout(variant)
    return frozenset(e.object for p in tpdos for e in p.mapping)


def is_pdo_object(obj: ObjRef) -> bool:
    return 0x1400 <= obj.index < 0x1C00


def apply_pdo_writes(
    profile: Profile,
    kind: Kind,
    pdos: Sequence[Pdo],
    node_id: int,
    writes: Iterable[tuple[ObjRef, Any]],
) -> list[Pdo]:
    """The PDOs as the device has them after ``writes`` (SDO downloads, in order).

    Starts from ``pdos`` and replays the writes to each PDO's COB-ID (sub 01h) and mapping
    (sub 00h = number of entries, 01h.. = entries). A PDO left with COB-ID bit 31 set or no
    entries is dropped (the device does not send it); a PDO number outside the layout is added
    when the writes give it both a valid COB-ID and a mapping. Raises PdoMappingError for a
    mapping longer than 8 bytes or an enabled entry never written.
    """
    state: dict[int, dict[str, Any]] = {}
    for p in pdos:
        entries = {i: entry_value(e.object, e.bits) for i, e in enumerate(p.mapping, start=1)}
        state[p.number] = {
            "pdo": p,
            "cob": pdo_cob_id(kind, p, node_id),
            "count": len(p.mapping),
            "entries": entries,
            "cob_written": False,
            "map_written": False,
        }
    _replay_writes(state, profile, kind, writes)
    out: list[Pdo] = []
    for number in sorted(state):
        pdo = _pdo_after_writes(kind, number, state[number])
        if pdo is not None:
            out.append(pdo)
    return out


def _replay_writes(
    state: dict[int, dict[str, Any]],
    profile: Profile,
    kind: Kind,
    writes: Iterable[tuple[ObjRef, Any]],
) -> None:
    """Each write to a PDO's COB-ID (sub 01h) or mapping into ``state`` (per PDO number)."""
    by_comm, by_map = _pdo_index_lookup(profile, kind)
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
        try:
            v = int(value, 0) if isinstance(value, str) else int(value)
        except ValueError:
            raise PdoMappingError(
                f"{kind.upper()}{number}: {obj} = {value!r} is not a number"
            ) from None
        if not is_map:
            st["cob"] = v
            st["cob_written"] = True
        elif obj.sub == 0:
            st["count"] = v
            st["map_written"] = True
        else:
            st["entries"][obj.sub] = v
            st["map_written"] = True


def _pdo_after_writes(kind: Kind, number: int, st: dict[str, Any]) -> Pdo | None:
    """The PDO ``number`` as its replayed ``st`` leaves it; None when the device does not send
    it (COB-ID bit 31, no entries, or a new PDO not given both a COB-ID and a mapping)."""
    base: Pdo | None = st["pdo"]
    if base is None and not (st["cob_written"] and st["map_written"]):
        return None
    if st["cob"] & COB_ID_INVALID or st["count"] == 0:
        return None
    if base is not None and not st["cob_written"] and not st["map_written"]:
        return base
    mapping = []
    for i in range(1, st["count"] + 1):
        raw = st["entries"].get(i)
        if raw is None:
            raise PdoMappingError(
                f"{kind.upper()}{number}: mapping sub-index {i} is enabled but never written"
            )
        obj, bits = decode_entry(raw)
        mapping.append({"object": obj, "bits": bits})
    fields: dict[str, Any] = {
        "number": number,
        "cob_id": st["cob"] & COB_ID_MASK_11BIT,
        "add_node_id": False,
        "mapping": mapping,
        "origin": base.origin if base is not None and not st["map_written"] else "config",
    }
    if base is not None:
        fields.update(
            transmission_type=base.transmission_type,
            event_timer_ms=base.event_timer_ms,
            inhibit_time_100us=base.inhibit_time_100us,
            sync_start=base.sync_start,
            description=base.description,
        )
    try:
        return Pdo.model_validate(fields)
    except ValueError as exc:
        raise PdoMappingError(f"{kind.upper()}{number}: {exc}") from None


def pdo_from_eds(p: EdsPdo) -> Pdo:
    """An EDS PDO as a layout entry (COB-ID as held, ``$NODEID`` already resolved)."""
    return Pdo(
        number=p.number,
        cob_id=p.cob_id & COB_ID_MASK_11BIT,
        add_node_id=False,
        transmission_type=p.transmission_type if p.transmission_type is not None else 254,
        event_timer_ms=p.event_timer_ms,
        inhibit_time_100us=p.inhibit_time_100us,
        sync_start=p.sync_start,
        mapping=[PdoEntry(object=o, bits=b) for o, b in p.entries],
        origin="eds",
    )


def parse_mapping_entry(text: str, od: Any, where: str) -> PdoEntry:
    """``"0x6000:01"`` (bit length from the EDS) or ``"0x6000:01/8"``; dummy entries name a
    data type (``"0x0005:00"`` = 8 bits, CiA 301 7.4.7.1)."""
    s = str(text)
    bits: int | None = None
    if "/" in s:
        s, b = s.rsplit("/", 1)
        try:
            bits = int(b, 0)
        except ValueError:
            raise PdoMappingError(f"{where}: {text!r}: bit length {b!r} is not a number") from None
    try:
        obj = ObjRef.parse(s)
    except ValueError as exc:
        raise PdoMappingError(f"{where}: {exc}") from None
    if obj.index >= 0x1000 and od_var(od, obj) is None:
        what = (
            f"{obj.index:04X}h has no sub-index {obj.sub:02X}h"
            if obj.index in od
            else "not in the EDS"
        )
        raise PdoMappingError(f"{where}: {obj}: {what}")
    known = object_bits(od, obj)
    if known is None:
        if obj.index < 0x1000:
            raise PdoMappingError(
                f"{where}: {obj} is not a dummy data type (0x0001..0x0007 and the like)"
            )
        if bits is None:
            raise PdoMappingError(
                f"{where}: {obj} is not in the EDS or has no fixed size; give 'index:sub/bits'"
            )
    if bits is None:
        bits = known
    assert bits is not None
    return PdoEntry(object=obj, bits=bits)


def pdo_setting(
    kind: Kind,
    number: int,
    setting: PdoSetup,
    current: Pdo | None,
    eds_pdo: EdsPdo | None,
    od: Any,
    node_id: int,
    where: str,
) -> Pdo | None:
    """The layout entry a node's ``tpdo:``/``rpdo:`` setting makes; None: PDO disabled."""
    if not setting.enabled:
        return None
    base = current if current is not None else (pdo_from_eds(eds_pdo) if eds_pdo else None)
    if setting.mapping is not None:
        mapping = [
            parse_mapping_entry(m, od, f"{where}.mapping[{i}]")
            for i, m in enumerate(setting.mapping)
        ]
    elif base is not None:
        mapping = list(base.mapping)
    else:
        raise PdoMappingError(
            f"{where}: {kind.upper()}{number} is not in the EDS; give its mapping"
        )
    if setting.cob_id is not None:
        cob = setting.cob_id
    elif eds_pdo is not None and (eds_pdo.cob_id & COB_ID_MASK_11BIT):
        cob = eds_pdo.cob_id
    elif base is not None:
        cob = pdo_cob_id(kind, base, node_id)
    else:
        try:
            cob = default_cob_id(kind, number) + node_id
        except ValueError as exc:
            raise PdoMappingError(f"{where}: {exc}") from None
    inhibit = None
    if setting.inhibit_ms is not None:
        inhibit = round(setting.inhibit_ms * 10)
        if abs(inhibit - setting.inhibit_ms * 10) > 1e-9:
            raise PdoMappingError(
                f"{where}.inhibit_ms: {setting.inhibit_ms} is not a multiple of 0.1 ms"
            )
    fields: dict[str, Any] = {
        "number": number,
        "cob_id": cob & COB_ID_MASK_11BIT,
        "add_node_id": False,
        "transmission_type": (
            setting.transmission
            if setting.transmission is not None
            else (base.transmission_type if base is not None else 254)
        ),
        "event_timer_ms": setting.event_timer_ms if setting.event_timer_ms is not None else (base.event_timer_ms if base else None),
        "inhibit_time_100us": inhibit if inhibit is not None else (base.inhibit_time_100us if base else None),
        "sync_start": setting.sync_start if setting.sync_start is not None else (base.sync_start if base else None),
        "mapping": mapping,
        "description": base.description if base is not None else "",
        "origin": "config",
    }  # fmt: skip
    try:
        return Pdo.model_validate(fields)
    except ValidationError as exc:
        msg = "; ".join(str(e["msg"]).removeprefix("Value error, ") for e in exc.errors())
        raise PdoMappingError(f"{where}: {msg}") from None


def apply_settings(
    kind: Kind,
    pdos: Sequence[Pdo],
    settings: Mapping[int, PdoSetup],
    eds: Sequence[EdsPdo],
    od: Any,
    node_id: int,
    key: str,
) -> list[Pdo]:
    """The layout after the node's ``tpdo:``/``rpdo:`` settings (by PDO number)."""
    by_number = {p.number: p for p in pdos}
    eds_by_number = {p.number: p for p in eds}
    for number, setting in sorted(settings.items()):
        new = pdo_setting(
            kind, number, setting, by_number.get(number), eds_by_number.get(number), od, node_id,
            f"{key}.{number}",
        )  # fmt: skip
        if new is None:
            by_number.pop(number, None)
        else:
            by_number[number] = new
    return [by_number[n] for n in sorted(by_number)]
