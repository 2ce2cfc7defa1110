"""One configured node's complete profile (``load_node_profile``): the profile (or none: an
EDS-only node) on the node's EDS or DCF, its PDO layout after the node's ``tpdo:``/``rpdo:``
settings and PDO writes (``profiles.layout``), and a signal for every mapped object (derived
from the EDS where the profile names none). Results are cached by the node's settings.

Imports: profiles.loader, profiles.device, profiles.layout, profiles.schema, canopen_gateway.eds.pdos,
canopen.cia301, canopen.objref, profiles.node_setup (the node is read as a ``NodeSetup``). Nothing of
bus/, modbus/, zenoh_bridge/, config.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from canopen_gateway.canopen.cia301 import TYPE_BITS
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.pdos import (
    FLOAT_TYPES,
    eds_pdos,
    object_name,
    signal_type,
    slug,
    unique_names,
)
from canopen_gateway.profiles.device import (
    STALE_EVENT_TIMER_MULTIPLE,
    device_supervision,
    stale_after_from_event_timers,
)
from canopen_gateway.profiles.layout import (
    PdoMappingError,
    apply_pdo_writes,
    apply_settings,
    is_pdo_object,
)
from canopen_gateway.profiles.loader import (
    EdsLayout,
    LoadedProfile,
    ProfileError,
    eds_layout,
    layout_objects,
    load_profile,
    read_eds,
    with_eds,
)
from canopen_gateway.profiles.node_setup import NodeSetup, SdoSetup
from canopen_gateway.profiles.schema import BootWrite, Pdo, Profile, Signal


def resolve_eds_path(eds: str, base_dir: Path | None) -> Path:
    p = Path(eds)
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return p.resolve()


def load_node_profile(node: NodeSetup, base_dir: Path | None = None) -> LoadedProfile:
    """The complete profile of one configured node (see the module docstring)."""
    return _load_node(node.cache_key(base_dir), node, base_dir)


_NODE_CACHE: dict[str, LoadedProfile] = {}


def _load_node(key: str, node: NodeSetup, base_dir: Path | None) -> LoadedProfile:
    hit = _NODE_CACHE.get(key)
    if hit is not None:
        return hit
    lp = _resolve_node(node, base_dir)
    if len(_NODE_CACHE) > 512:
        _NODE_CACHE.clear()
    _NODE_CACHE[key] = lp
    return lp


def _resolve_node(node: NodeSetup, base_dir: Path | None) -> LoadedProfile:
    """The node's profile on its EDS, its PDO layout as the node's settings leave it, the
    signals that layout maps, the layout's warnings and the staleness of an unsupervised node."""
    base = _base_profile(node, base_dir)
    prof = base.profile
    tpdos, rpdos, lay, explicit = _layout(node, base)
    if node.configure:
        tpdos, rpdos = _apply_node_settings(node, base, tpdos, rpdos)
    signals = _signals(base, tpdos, rpdos, explicit)
    warnings: list[str] = []
    for kind, pdos in (("tpdo", tpdos), ("rpdo", rpdos)):
        for p in pdos:
            if p.origin == "eds":  # a layout of the profile or the config is checked with its key
                warnings += lay.warnings.get((kind, p.number), [])
    update: dict[str, Any] = {"signals": signals}
    if prof.pdo_variants is None:
        update.update(tpdos=tpdos, rpdos=rpdos)
    stale_ms, notes = _unsupervised_notes(node, base, tpdos)
    return LoadedProfile(prof.model_copy(update=update), base.path, base.eds_path, base.od,
                         tuple(warnings), stale_ms, tuple(notes))  # fmt: skip


def _base_profile(node: NodeSetup, base_dir: Path | None) -> LoadedProfile:
    """The named profile on its (or the node's) EDS, else a bare profile made of the EDS."""
    if node.profile:
        base = load_profile(node.profile, base_dir)
        if node.eds:
            eds_path = resolve_eds_path(node.eds, base_dir)
            eds = read_eds(eds_path)
            base = with_eds(base.profile, base.path, eds_path, eds.od)
        elif base.profile.eds is None:
            raise ProfileError(f"{base.path}: names no eds; give the node's eds")
        # a DCF carries the values the device holds: read its ParameterValues
        return base
    if not node.eds:
        raise ProfileError("a node needs a profile, an eds, or both")
    eds_path = resolve_eds_path(node.eds, base_dir)
    eds = read_eds(eds_path)
    profile = Profile(
        family=slug(eds_path.stem) or "device",
        title=eds.product_name,
        eds=eds_path.name,
        signals=[],
        boot=device_supervision(eds.od),
    )
    return with_eds(profile, eds_path, eds_path, eds.od)


def _layout(node: NodeSetup, base: LoadedProfile) -> tuple[list[Pdo], list[Pdo], EdsLayout, bool]:
    """The PDOs before the node's settings: the profile's layout (``explicit``) or the EDS's;
    an EDS PDO the gateway cannot decode raises unless the node's settings name it."""
    prof = base.profile
    explicit = bool(prof.tpdos or prof.rpdos or prof.pdo_variants)
    if explicit:
        variant = node.pdo_variant
        if prof.pdo_variants is None or variant not in prof.pdo_variants.variants:
            variant = None  # an unknown variant is reported by the config check
        tpdos, rpdos = prof.layout(variant)
        lay = EdsLayout([], [], {}, {})
    else:
        lay = eds_layout(base.od, node.node_id, base.eds_path)
        tpdos, rpdos = lay.tpdos, lay.rpdos
    for (kind, number), why in lay.refused.items():
        if number not in (node.tpdo if kind == "tpdo" else node.rpdo):
            raise ProfileError(why)  # unless the node's tpdo:/rpdo: settings remap or disable it
    return tpdos, rpdos, lay, explicit


def _apply_node_settings(
    node: NodeSetup, base: LoadedProfile, tpdos: list[Pdo], rpdos: list[Pdo]
) -> tuple[list[Pdo], list[Pdo]]:
    """The node's ``tpdo:``/``rpdo:`` settings, then the PDO objects its and the profile's
    ``sdo`` writes set, applied to the layout."""
    prof, od, node_id = base.profile, base.od, node.node_id
    if (node.tpdo or node.rpdo) and prof.pdo_variants is not None:
        raise ProfileError(
            f"profile {prof.family} chooses its PDO layout by {prof.pdo_variants.selector} "
            "(pdo_variant); tpdo:/rpdo: cannot remap it"
        )
    for kind, settings in (("tpdo", node.tpdo), ("rpdo", node.rpdo)):
        try:
            remapped = apply_settings(kind, tpdos if kind == "tpdo" else rpdos, settings,  # type: ignore[arg-type]
                                 eds_pdos(od, node_id, kind), od, node_id, kind)  # type: ignore[arg-type]  # fmt: skip
        except PdoMappingError as exc:
            head, _, rest = str(exc).partition(": ")
            raise ProfileError(rest or str(exc), key=head) from None
        if kind == "tpdo":
            tpdos = remapped
        else:
            rpdos = remapped
    try:
        everything: list[BootWrite | SdoSetup] = [*prof.boot.sdo, *node.sdo]
        writes = [(w.object, w.value) for w in everything if is_pdo_object(w.object)]
        if writes:
            tpdos = apply_pdo_writes(prof, "tpdo", tpdos, node_id, writes)
            rpdos = apply_pdo_writes(prof, "rpdo", rpdos, node_id, writes)
    except PdoMappingError as exc:
        raise ProfileError(str(exc), key="") from None
    return tpdos, rpdos


def _signals(
    base: LoadedProfile, tpdos: list[Pdo], rpdos: list[Pdo], explicit: bool
) -> list[Signal]:
    """The profile's signals (an SDO signal the node's layout maps becomes a PDO one), then one
    signal per object the layout maps that no signal names (not for the profile's own layout)."""
    prof = base.profile
    own_t, own_r = layout_objects(prof)
    t_objs = {e.object for p in tpdos for e in p.mapping if e.object.index >= 0x1000}
    r_objs = {e.object for p in rpdos for e in p.mapping if e.object.index >= 0x1000}
    signals: list[Signal] = []
    for s in prof.signals:
        if (
            s.transport == "sdo"
            and (s.object in t_objs or s.object in r_objs)
            and not (s.object in own_t or s.object in own_r)
        ):
            # mapped by the node's configuration (e.g. MSK5000 5122h:01 by the 4.3.1.2 remap)
            s = s.model_copy(update={"transport": "pdo"})
        signals.append(s)
    named = {s.object for s in signals}
    new: list[ObjRef] = []
    for p in [*tpdos, *rpdos]:
        if explicit and p.origin == "profile":
            continue  # the profile's own layout: unnamed entries stay unnamed (dummies)
        for e in p.mapping:
            if e.object.index >= 0x1000 and e.object not in named and e.object not in new:
                new.append(e.object)
    names = unique_names(base.od, new, {s.name for s in signals})
    for o in new:
        signal = _mapped_signal(base, o, names[o], [*tpdos, *rpdos], o in r_objs)
        if signal is not None:
            signals.append(signal)
    return signals


def _mapped_signal(
    base: LoadedProfile, o: ObjRef, name: str, pdos: list[Pdo], writable: bool
) -> Signal | None:
    """The signal of an object a PDO maps and no signal names; None when it has no value."""
    var = base.od_var(o)
    if var is None:
        return None  # not in the EDS: reported by the check of the layout
    typ = signal_type(var)
    if typ is None:
        return None  # REAL64, DOMAIN...: decoded at its offset and dropped (warned above)
    widths = {e.bits for p in pdos for e in p.mapping if e.object == o}
    if var.data_type in FLOAT_TYPES and TYPE_BITS.get(var.data_type) not in widths:
        return None  # a float mapped with another length has no value (warned above)
    length = None
    if typ in ("string", "bytes"):
        bits = next(e.bits for p in pdos for e in p.mapping if e.object == o)
        length = max(1, bits // 8)
    return Signal(
        name=name,
        object=o,
        type=typ,  # type: ignore[arg-type]
        access="rw" if writable else "ro",
        transport="pdo",
        length=length,
        description=f"{object_name(base.od, o)} ({o})",
    )


def _unsupervised_notes(
    node: NodeSetup, base: LoadedProfile, tpdos: list[Pdo]
) -> tuple[int | None, list[str]]:
    """For an EDS-only node without heartbeat or guarding: the derived ``stale_after_ms`` and
    the note that says so."""
    prof = base.profile
    if node.profile or node.supervision is not None or prof.boot.supervision != "none":
        return None, []
    stale_ms = stale_after_from_event_timers(tpdos)
    age = (
        f"its values go stale {stale_ms} ms after their last TPDO "
        f"({STALE_EVENT_TIMER_MULTIPLE} x the longest TPDO event timer)"
        if stale_ms
        else "no TPDO has an event timer, so its values never go stale by age"
    )
    return stale_ms, [
        f"{base.eds_path.name} has neither 1017h (heartbeat) nor 100Ch/100Dh (node guarding): "
        f"a lost device cannot be detected otherwise; {age}"
    ]
