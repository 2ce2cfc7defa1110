"""Built-in device profiles and the loader for profile + EDS pairs.

``load_profile("sgh10")`` finds ``gateway/profiles/sgh10.yaml``; a path to a ``.yaml`` file loads
a user's own profile, its ``eds:`` resolved next to it. The EDS is parsed with canopen's
``import_od``; every object the profile names must exist in it.

Imports: schema, objref, canopen, yaml. Nothing of bus/, modbus/, zenoh_bridge/.
"""

from __future__ import annotations

import functools
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import canopen
import yaml
from pydantic import ValidationError

from gateway.objref import ObjRef
from gateway.profiles.schema import Profile

PROFILE_DIR = Path(__file__).parent


class ProfileError(Exception):
    """A profile or its EDS cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class LoadedProfile:
    profile: Profile
    path: Path
    eds_path: Path
    od: canopen.ObjectDictionary

    @property
    def family(self) -> str:
        return self.profile.family

    def od_var(self, obj: ObjRef) -> canopen.objectdictionary.ODVariable | None:
        try:
            entry = self.od[obj.index]
        except KeyError:
            return None
        if isinstance(entry, canopen.objectdictionary.ODVariable):
            return entry if obj.sub == 0 else None
        try:
            return entry[obj.sub]
        except KeyError:
            return None


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
    """Parse an EDS with canopen, turning its warnings into a ProfileError."""
    log = logging.getLogger("canopen.objectdictionary.eds")
    records: list[str] = []

    class _Catch(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.levelno >= logging.WARNING:
                records.append(record.getMessage())

    h = _Catch()
    log.addHandler(h)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            od = canopen.import_od(str(path), node_id)
    except Exception as exc:  # canopen raises many kinds on a bad file
        raise ProfileError(f"{path}: EDS cannot be parsed: {exc}") from exc
    finally:
        log.removeHandler(h)
    problems = records + [str(w.message) for w in caught]
    if problems:
        raise ProfileError(f"{path}: EDS warnings: {'; '.join(problems)}")
    return od


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
    eds_path = (path.parent / profile.eds).resolve()
    if not eds_path.exists():
        raise ProfileError(f"{path}: eds: file {eds_path} does not exist")
    od = import_eds(eds_path)
    lp = LoadedProfile(profile, path, eds_path, od)
    _check_objects(lp)
    return lp


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
