"""Device profiles from their files: a built-in or a user's profile ``.yaml`` on its EDS, read,
checked and completed (``load_profile``), and the reading of an EDS on the profile's terms
(``import_eds``, ``read_eds``, ``eds_layout``).

Every object the profile names must exist in the EDS; signal types, access and transport the
profile leaves out are taken from the EDS and the PDO layout (``complete``).

Imports: profiles.schema, profiles.layout, canopen_gateway.eds, cia301, objref, canopen, yaml, pydantic.
Nothing of bus/, modbus/, zenoh_bridge/, config.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import canopen
import yaml
from pydantic import ValidationError

from canopen_gateway.canopen.cia301 import COB_ID_INVALID
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds import EdsError, EdsFile, dictionary_for_node, load_eds, near_names
from canopen_gateway.eds.pdos import access_of, eds_pdos, mapping_findings, od_var, signal_type
from canopen_gateway.profiles.layout import pdo_from_eds
from canopen_gateway.profiles.schema import Pdo, Profile, Signal

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
            raise ProfileError(f"profile file {p} does not exist{near_names(p, ('.yaml', '.yml'))}")
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


def read_eds(path: Path) -> Any:
    try:
        return load_eds(path)
    except EdsError as exc:
        raise ProfileError(str(exc)) from None


# --------------------------------------------------------------------------- completion


def layout_objects(profile: Profile) -> tuple[set[ObjRef], set[ObjRef]]:
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
class EdsLayout:
    tpdos: list[Pdo]
    rpdos: list[Pdo]
    refused: dict[tuple[str, int], str]  # (kind, number) -> why the gateway cannot decode it
    warnings: dict[tuple[str, int], list[str]]


def eds_layout(od: canopen.ObjectDictionary, node_id: int | None, eds_path: Path | None = None) -> EdsLayout:
    """The enabled PDOs of the file; one the gateway would decode wrongly is left out and
    named in ``refused`` (file, line, section, PDO, object in one line)."""
    eds_file = eds_file_or_none(eds_path) if eds_path is not None else None
    out = EdsLayout([], [], {}, {})
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
        raise ProfileError(f"{path}: eds: file {eds_path} does not exist{near_names(eds_path, ('.eds', '.dcf'))}")
    eds = read_eds(eds_path)
    return with_eds(profile, path, eds_path, eds.od)


def with_eds(profile: Profile, path: Path, eds_path: Path, od: canopen.ObjectDictionary) -> LoadedProfile:
    t, r = layout_objects(profile)
    if not (profile.tpdos or profile.rpdos or profile.pdo_variants):
        lay = eds_layout(od, None)
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


def eds_file_or_none(path: Path) -> EdsFile | None:
    try:
        return load_eds(path)
    except EdsError:
        return None
