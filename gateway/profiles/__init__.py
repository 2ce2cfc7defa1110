"""Device profiles (overlays on an EDS) and the loader that makes a node's complete profile.

``load_profile("sgh10")`` finds ``gateway/profiles/sgh10.yaml``; a path to a ``.yaml`` file loads
a user's own profile, its ``eds:`` resolved next to it. The EDS is checked and read by
``gateway.eds.load_eds``; every object the profile names must exist in it; signal types,
access and transport the profile leaves out are taken from the EDS and the PDO layout.

``load_node_profile(node, base_dir)`` is what the rest of the gateway uses for a configured
node: the profile (or none: an EDS-only node) on the node's EDS or DCF, its PDO layout after the
node's ``tpdo:``/``rpdo:`` settings and PDO writes (``layout``), and a signal for every mapped
object (derived from the EDS where the profile names none). One result, used by the boot-step
builder, the codecs, the register map, the Zenoh keys and the simulator.

Imports: schema, layout, gateway.eds, cia301, objref, canopen, yaml. Nothing of bus/, modbus/,
zenoh_bridge/, config.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import canopen
import yaml
from pydantic import ValidationError

from gateway.cia301 import COB_ID_INVALID, TYPE_BITS
from gateway.eds import EdsError, EdsFile, dictionary_for_node, load_eds
from gateway.eds.pdos import (
    FLOAT_TYPES,
    access_of,
    eds_pdos,
    mapping_findings,
    object_name,
    od_var,
    signal_type,
    slug,
    unique_names,
)
from gateway.objref import ObjRef
from gateway.profiles.layout import (
    PdoMappingError,
    PdoSettingLike,
    apply_pdo_writes,
    apply_settings,
    is_pdo_object,
    pdo_from_eds,
)
from gateway.profiles.schema import Boot, Pdo, Profile, Signal

PROFILE_DIR = Path(__file__).parent


class ProfileError(Exception):
    """A profile or its EDS cannot be used; the message names the file and the problem.

    ``key``: where in a node's config the problem lies ("" the node as a whole, e.g.
    ``tpdo.1.mapping[0]``), None when it is in the profile or EDS file itself."""

    def __init__(self, message: str, key: str | None = None):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class LoadedProfile:
    profile: Profile
    path: Path
    eds_path: Path
    od: canopen.ObjectDictionary
    #: what the gateway skips or reads leniently for this node (file:line: [section]: ...)
    warnings: tuple[str, ...] = ()
    #: an EDS-only node without supervision: the data age after which its values are stale
    stale_after_ms: int | None = None
    #: advice for ``check`` about the node (e.g. a loss that cannot be detected)
    notes: tuple[str, ...] = ()

    @property
    def family(self) -> str:
        return self.profile.family

    def od_var(self, obj: ObjRef) -> canopen.objectdictionary.ODVariable | None:
        return od_var(self.od, obj)


def builtin_profiles() -> list[str]:
    return sorted(p.stem for p in PROFILE_DIR.glob("*.yaml"))


def resolve_profile_path(name_or_path: str, base_dir: Path | None = None) -> Path:
    if name_or_path.endswith((".yaml", ".yml")):
        p = Path(name_or_path)
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        if not p.exists():
            raise ProfileError(f"profile file {p} does not exist")
        return p
    p = PROFILE_DIR / f"{name_or_path}.yaml"
    if not p.exists():
        raise ProfileError(
            f"unknown profile {name_or_path!r}; built-in: {', '.join(builtin_profiles())} "
            "(or give a path to a profile .yaml)"
        )
    return p


def import_eds(path: Path, node_id: int | None = None) -> canopen.ObjectDictionary:
    """The dictionary of an EDS with ``$NODEID`` resolved for ``node_id``; an unreadable file
    is a ProfileError."""
    try:
        return dictionary_for_node(path, node_id)
    except EdsError as exc:
        raise ProfileError(str(exc)) from None


def _eds(path: Path) -> Any:
    try:
        return load_eds(path)
    except EdsError as exc:
        raise ProfileError(str(exc)) from None


# --------------------------------------------------------------------------- completion


def _layout_objects(profile: Profile) -> tuple[set[ObjRef], set[ObjRef]]:
    """Objects in the TPDOs / RPDOs of every layout the profile gives (all variants)."""
    t: set[ObjRef] = set()
    r: set[ObjRef] = set()
    pdos = [(p, t) for p in profile.tpdos] + [(p, r) for p in profile.rpdos]
    if profile.pdo_variants:
        for v in profile.pdo_variants.variants.values():
            pdos += [(p, t) for p in v.tpdos] + [(p, r) for p in v.rpdos]
    for p, into in pdos:
        into.update(e.object for e in p.mapping)
    return t, r


@dataclass(frozen=True)
class _EdsLayout:
    tpdos: list[Pdo]
    rpdos: list[Pdo]
    refused: dict[tuple[str, int], str]  # (kind, number) -> why the gateway cannot decode it
    warnings: dict[tuple[str, int], list[str]]


def _eds_layout(od: canopen.ObjectDictionary, node_id: int | None, eds_path: Path | None = None) -> _EdsLayout:
    """The enabled PDOs of the file; one the gateway would decode wrongly is left out and
    named in ``refused`` (file, line, section, PDO, object in one line)."""
    eds_file = _eds_file(eds_path) if eds_path is not None else None
    out = _EdsLayout([], [], {}, {})
    for kind, into in (("tpdo", out.tpdos), ("rpdo", out.rpdos)):
        for p in eds_pdos(od, node_id, kind):  # type: ignore[arg-type]
            if p.cob_id & COB_ID_INVALID or not (p.entries or p.gaps):
                continue
            found = mapping_findings(od, p.kind, p.number, p.map_index, p.entries, p.gaps, p.count)
            lines = [str(eds_file.problem(f.obj, f.message)) if eds_file else f"{eds_path}: {f.message}" for f in found]  # fmt: skip
            fatal = [line for f, line in zip(found, lines, strict=True) if f.fatal]
            if fatal:
                out.refused[(kind, p.number)] = fatal[0]
                continue
            out.warnings[(kind, p.number)] = lines
            into.append(pdo_from_eds(p))
    return out


def _complete(
    sig: Signal, od: canopen.ObjectDictionary, tpdo_objs: set[ObjRef], rpdo_objs: set[ObjRef], where: str
) -> Signal:
    """Fill what a signal leaves to the EDS: type, access, transport, string length."""
    var = od_var(od, sig.object)
    upd: dict[str, Any] = {}
    if sig.type is None:
        t = signal_type(var)
        if t is None:
            raise ProfileError(
                f"{where}: signals[{sig.name}]: {sig.object} has no type the gateway serves; give type"
            )
        upd["type"] = t
    typ = upd.get("type", sig.type)
    if typ in ("string", "bytes") and sig.length is None:
        default = var.default if var is not None else None
        if not default:
            raise ProfileError(f"{where}: signals[{sig.name}]: type {typ} needs a length in bytes")
        upd["length"] = len(default if isinstance(default, bytes) else str(default).encode("utf-8"))
    transport = sig.transport
    if transport is None:
        transport = "pdo" if sig.object in tpdo_objs or sig.object in rpdo_objs else "sdo"
        upd["transport"] = transport
    if sig.access is None:
        if transport == "pdo":
            upd["access"] = "rw" if sig.object in rpdo_objs else "ro"
        else:
            upd["access"] = access_of(var)
    return sig.model_copy(update=upd) if upd else sig


@functools.lru_cache(maxsize=64)
def _load(path: Path) -> LoadedProfile:
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ProfileError(f"{path}: {exc}") from exc
    try:
        profile = Profile.model_validate(raw)
    except ValidationError as exc:
        lines = []
        for e in exc.errors():
            loc = ".".join(str(p) for p in e["loc"])
            lines.append(f"{path}: {loc}: {e['msg']}")
        raise ProfileError("\n".join(lines)) from None
    if profile.eds is None:
        # an overlay without its own EDS: completed per node (load_node_profile)
        return LoadedProfile(profile, path, path, canopen.ObjectDictionary())
    eds_path = (path.parent / profile.eds).resolve()
    if not eds_path.exists():
        raise ProfileError(f"{path}: eds: file {eds_path} does not exist")
    eds = _eds(eds_path)
    return _with_eds(profile, path, eds_path, eds.od)


def _with_eds(profile: Profile, path: Path, eds_path: Path, od: canopen.ObjectDictionary) -> LoadedProfile:
    t, r = _layout_objects(profile)
    if not (profile.tpdos or profile.rpdos or profile.pdo_variants):
        lay = _eds_layout(od, None)
        et, er = lay.tpdos, lay.rpdos
        t |= {e.object for p in et for e in p.mapping}
        r |= {e.object for p in er for e in p.mapping}
    lp = LoadedProfile(profile, path, eds_path, od)
    _check_objects(lp)
    signals = [_complete(s, od, t, r, str(path)) for s in profile.signals]
    return LoadedProfile(profile.model_copy(update={"signals": signals}), path, eds_path, od)


def _check_objects(lp: LoadedProfile) -> None:
    p = lp.profile
    missing: list[str] = []
    for s in p.signals:
        if lp.od_var(s.object) is None:
            missing.append(f"signals[{s.name}].object {s.object}")
    pdos = [("tpdos", x) for x in p.tpdos] + [("rpdos", x) for x in p.rpdos]
    if p.pdo_variants:
        for val, v in p.pdo_variants.variants.items():
            pdos += [(f"pdo_variants.{val}.tpdos", x) for x in v.tpdos]
            pdos += [(f"pdo_variants.{val}.rpdos", x) for x in v.rpdos]
    for where, pdo in pdos:
        for e in pdo.mapping:
            if e.object.index < 0x1000:
                continue  # dummy mapping of a data type (DS-301 0002h..0007h)
            if lp.od_var(e.object) is None:
                missing.append(f"{where}[{pdo.number}].mapping {e.object}")
    if missing:
        raise ProfileError(f"{lp.path}: objects not in {lp.eds_path.name}: {', '.join(missing)}")


def load_profile(name_or_path: str, base_dir: Path | None = None) -> LoadedProfile:
    return _load(resolve_profile_path(name_or_path, base_dir).resolve())


# --------------------------------------------------------------------------- one node


class NodeLike(Protocol):
    """What the loader reads of a node's configuration (``gateway.config.NodeConfig``)."""

    @property
    def node_id(self) -> int: ...
    @property
    def profile(self) -> str | None: ...
    @property
    def eds(self) -> str | None: ...
    @property
    def pdo_variant(self) -> int | None: ...
    @property
    def configure(self) -> bool: ...
    @property
    def sdo(self) -> Sequence[Any]: ...
    @property
    def tpdo(self) -> Mapping[int, PdoSettingLike]: ...
    @property
    def rpdo(self) -> Mapping[int, PdoSettingLike]: ...


def _node_key(node: NodeLike, base_dir: Path | None) -> str:
    def dump(v: Any) -> Any:
        return v.model_dump(mode="json") if hasattr(v, "model_dump") else str(v)

    return json.dumps(
        {
            "profile": node.profile,
            "eds": node.eds,
            "node_id": node.node_id,
            "variant": node.pdo_variant,
            "configure": node.configure,
            "sdo": [dump(w) for w in node.sdo],
            "tpdo": {str(k): dump(v) for k, v in (node.tpdo or {}).items()},
            "rpdo": {str(k): dump(v) for k, v in (node.rpdo or {}).items()},
            "base": str(base_dir),
        },
        sort_keys=True,
        default=str,
    )


def resolve_eds_path(eds: str, base_dir: Path | None) -> Path:
    p = Path(eds)
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return p.resolve()


def load_node_profile(node: NodeLike, base_dir: Path | None = None) -> LoadedProfile:
    """The complete profile of one configured node (see the module docstring)."""
    return _load_node(_node_key(node, base_dir), node, base_dir)


_NODE_CACHE: dict[str, LoadedProfile] = {}


def _load_node(key: str, node: NodeLike, base_dir: Path | None) -> LoadedProfile:
    hit = _NODE_CACHE.get(key)
    if hit is not None:
        return hit
    lp = _resolve_node(node, base_dir)
    if len(_NODE_CACHE) > 512:
        _NODE_CACHE.clear()
    _NODE_CACHE[key] = lp
    return lp


def _resolve_node(node: NodeLike, base_dir: Path | None) -> LoadedProfile:
    if node.profile:
        base = load_profile(node.profile, base_dir)
        if node.eds:
            eds_path = resolve_eds_path(node.eds, base_dir)
            eds = _eds(eds_path)
            base = _with_eds(base.profile, base.path, eds_path, eds.od)
        elif base.profile.eds is None:
            raise ProfileError(f"{base.path}: names no eds; give the node's eds")
        # a DCF carries the values the device holds: read its ParameterValues
    else:
        if not node.eds:
            raise ProfileError("a node needs a profile, an eds, or both")
        eds_path = resolve_eds_path(node.eds, base_dir)
        eds = _eds(eds_path)
        profile = Profile(
            family=slug(eds_path.stem) or "device",
            title=eds.product_name,
            eds=eds_path.name,
            signals=[],
            boot=device_supervision(eds.od),
        )
        base = _with_eds(profile, eds_path, eds_path, eds.od)
    prof = base.profile
    od = base.od
    node_id = node.node_id
    explicit = bool(prof.tpdos or prof.rpdos or prof.pdo_variants)
    if explicit:
        variant = node.pdo_variant
        if prof.pdo_variants is None or variant not in prof.pdo_variants.variants:
            variant = None  # an unknown variant is reported by the config check
        tpdos, rpdos = prof.layout(variant)
        lay = _EdsLayout([], [], {}, {})
    else:
        lay = _eds_layout(od, node_id, base.eds_path)
        tpdos, rpdos = lay.tpdos, lay.rpdos
    for (kind, number), why in lay.refused.items():
        if number not in ((node.tpdo if kind == "tpdo" else node.rpdo) or {}):
            raise ProfileError(why)  # unless the node's tpdo:/rpdo: settings remap or disable it
    if node.configure:
        if (node.tpdo or node.rpdo) and prof.pdo_variants is not None:
            raise ProfileError(
                f"profile {prof.family} chooses its PDO layout by {prof.pdo_variants.selector} "
                "(pdo_variant); tpdo:/rpdo: cannot remap it"
            )
        for kind, settings in (("tpdo", node.tpdo), ("rpdo", node.rpdo)):
            try:
                remapped = apply_settings(kind, tpdos if kind == "tpdo" else rpdos, settings or {},  # type: ignore[arg-type]
                                     eds_pdos(od, node_id, kind), od, node_id, kind)  # type: ignore[arg-type]  # fmt: skip
            except PdoMappingError as exc:
                head, _, rest = str(exc).partition(": ")
                raise ProfileError(rest or str(exc), key=head) from None
            if kind == "tpdo":
                tpdos = remapped
            else:
                rpdos = remapped
        try:
            writes = [
                (ObjRef.parse(w.object), w.value)
                for w in [*prof.boot.sdo, *node.sdo]
                if is_pdo_object(ObjRef.parse(w.object))
            ]
            if writes:
                tpdos = apply_pdo_writes(prof, "tpdo", tpdos, node_id, writes)
                rpdos = apply_pdo_writes(prof, "rpdo", rpdos, node_id, writes)
        except PdoMappingError as exc:
            raise ProfileError(str(exc), key="") from None
    own_t, own_r = _layout_objects(prof)
    t_objs = {e.object for p in tpdos for e in p.mapping if e.object.index >= 0x1000}
    r_objs = {e.object for p in rpdos for e in p.mapping if e.object.index >= 0x1000}
    signals: list[Signal] = []
    for s in prof.signals:
        if s.transport == "sdo" and (s.object in t_objs or s.object in r_objs) and not (
            s.object in own_t or s.object in own_r
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
    warnings: list[str] = []
    for kind, pdos in (("tpdo", tpdos), ("rpdo", rpdos)):
        for p in pdos:
            if p.origin == "eds":  # a layout of the profile or the config is checked with its key
                warnings += lay.warnings.get((kind, p.number), [])
    names = unique_names(od, new, {s.name for s in signals})
    for o in new:
        var = od_var(od, o)
        if var is None:
            continue  # not in the EDS: reported by the check of the layout
        typ = signal_type(var)
        if typ is None:
            continue  # REAL64, DOMAIN...: decoded at its offset and dropped (warned above)
        widths = {e.bits for p in [*tpdos, *rpdos] for e in p.mapping if e.object == o}
        if var.data_type in FLOAT_TYPES and TYPE_BITS.get(var.data_type) not in widths:
            continue  # a float mapped with another length has no value (warned above)
        length = None
        if typ in ("string", "bytes"):
            bits = next(e.bits for p in [*tpdos, *rpdos] for e in p.mapping if e.object == o)
            length = max(1, bits // 8)
        signals.append(
            Signal(
                name=names[o],
                object=o,
                type=typ,  # type: ignore[arg-type]
                access="rw" if o in r_objs else "ro",
                transport="pdo",
                length=length,
                description=f"{object_name(od, o)} ({o})",
            )
        )
    update: dict[str, Any] = {"signals": signals}
    if prof.pdo_variants is None:
        update.update(tpdos=tpdos, rpdos=rpdos)
    stale_ms: int | None = None
    notes: list[str] = []
    if not node.profile and getattr(node, "supervision", None) is None and prof.boot.supervision == "none":
        stale_ms = stale_after_from_event_timers(tpdos)
        age = (
            f"its values go stale {stale_ms} ms after their last TPDO "
            f"({STALE_EVENT_TIMER_MULTIPLE} x the longest TPDO event timer)"
            if stale_ms
            else "no TPDO has an event timer, so its values never go stale by age"
        )
        notes.append(
            f"{base.eds_path.name} has neither 1017h (heartbeat) nor 100Ch/100Dh (node guarding): "
            f"a lost device cannot be detected otherwise; {age}"
        )
    return LoadedProfile(prof.model_copy(update=update), base.path, base.eds_path, od, tuple(warnings),
                         stale_ms, tuple(notes))  # fmt: skip


#: an EDS-only node without supervision: values are stale after this many event timer periods
STALE_EVENT_TIMER_MULTIPLE = 3


def stale_after_from_event_timers(tpdos: Sequence[Pdo]) -> int | None:
    """``stale_after_ms`` of a node the gateway cannot supervise: 3 x the longest event timer
    of its TPDOs (None when no TPDO has one)."""
    timers = [p.event_timer_ms for p in tpdos if p.event_timer_ms]
    return STALE_EVENT_TIMER_MULTIPLE * max(timers) if timers else None


def device_supervision(od: canopen.ObjectDictionary) -> Boot:
    """How an EDS-only node is supervised when its config does not say: heartbeat when the
    device has a writable 1017h (CiA 301 7.5.2.25), else node guarding when it has writable
    100Ch and 100Dh and no 1017h (guard time and life time factor from the file when not 0;
    else 100 ms and 3), else none."""
    def settable(obj: ObjRef) -> canopen.objectdictionary.ODVariable | None:
        var = od_var(od, obj)  # an integer the gateway can write (a damaged entry is not)
        ok = var is not None and var.data_type in (0x5, 0x6, 0x7) and var.access_type in ("rw", "wo", "rww", "rwr")
        return var if ok else None

    hb = settable(ObjRef(0x1017, 0))
    if hb is not None:
        lo, hi = hb.min, hb.max  # a file whose limits exclude 100 ms: the nearest allowed time
        if isinstance(lo, int) and isinstance(hi, int) and 0 < hi and lo <= hi and not lo <= 100 <= hi:
            return Boot(heartbeat_ms=min(max(100, lo, 1), hi, 65535))
        return Boot()
    gt, ltf = settable(ObjRef(0x100C, 0)), settable(ObjRef(0x100D, 0))
    if gt is not None and ltf is not None and (0x1017 not in od or od_var(od, ObjRef(0x1017, 0)) is None):
        gt_ms = gt.default if gt is not None and isinstance(gt.default, int) and 0 < gt.default <= 65535 else 100
        lt = ltf.default if ltf is not None and isinstance(ltf.default, int) and 0 < ltf.default <= 255 else 3
        return Boot(supervision="guarding", guard_time_ms=gt_ms, life_time_factor=lt)
    return Boot(supervision="none")


def _eds_file(path: Path) -> EdsFile | None:
    try:
        return load_eds(path)
    except EdsError:
        return None


#: CiA 306 placeholders: a VendorNumber / ProductNumber of 0 or all ones says nothing
_NOT_GIVEN = (0, 0xFFFFFFFF)


def expected_identity(lp: LoadedProfile) -> tuple[tuple[ObjRef, int], ...]:
    """What the device at this node must hold in 1018h (CiA 301 7.5.2.20), as its EDS/DCF
    says: sub 01h = VendorNumber and 02h = ProductNumber of [DeviceInfo] when the file gives
    both, and for a DCF sub 04h = the ParameterValue of 1018h:04 (the serial number of the
    commissioned device). Empty when the file gives no identity. Only the sub-indices the file
    defines are compared (CiA 301 makes only 1018h:01 mandatory: a file with 1018h:01 alone
    says its devices have no product code to read). A number the file contradicts
    itself on ([DeviceInfo] and the value of 1018h differ; ``eds lint`` warns) is not compared:
    the file does not say which device it describes, and a right device must not be refused."""
    info = lp.od.device_information
    vendor, product = info.vendor_number, info.product_number
    if vendor in (None, *_NOT_GIVEN) or product in (None, *_NOT_GIVEN):
        return ()
    out = []
    for sub, given in ((1, int(vendor)), (2, int(product))):
        var = od_var(lp.od, ObjRef(0x1018, sub))
        if var is None:
            continue
        held = getattr(var, "value", None)
        if held is None:
            held = getattr(var, "default", None)
        if isinstance(held, int) and held not in _NOT_GIVEN and held != given:
            continue
        out.append((ObjRef(0x1018, sub), given))
    serial = od_var(lp.od, ObjRef(0x1018, 4))
    held = getattr(serial, "value", None)
    if lp.eds_path.suffix.lower() == ".dcf" and isinstance(held, int) and held not in _NOT_GIVEN:
        out.append((ObjRef(0x1018, 4), held))
    return tuple(out)


def node_verifies_mapping(lp: LoadedProfile, node: Any, eds_only: bool) -> bool:
    """``verify_mapping``: the node's setting, else on for EDS-only nodes and for profiles
    that ask for it; never for a profile whose mapping objects do not describe the layout."""
    setting = getattr(node, "verify_mapping", None)
    if lp.profile.verify_mapping is False:
        return False
    if setting is not None:
        return bool(setting)
    return eds_only or bool(lp.profile.verify_mapping)
