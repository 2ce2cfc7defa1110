"""EDS / DCF knowledge: a strict loader, the PDOs an EDS describes, and signals derived from it.

``load_eds(path)`` checks the file (``parse.check_text``: every problem with file, line and
section, in the spirit of Lely's ``dcfchk``), then reads it with canopen's ``import_od``; a
warning of canopen is an error too. ``pdos.eds_pdos`` lists the TPDOs and RPDOs of the
dictionary (communication and mapping objects 1400h-1BFFh, ``$NODEID`` resolved),
``pdos.derived_signals`` names the mapped objects (ParameterName slugs, unique per node),
``show.render`` prints a dictionary and its PDOs as tables.

Imports: canopen, gateway.objref and the standard library. Nothing else of the gateway (the
profile loader imports this package, not the other way round).
"""

from __future__ import annotations

import functools
import io
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import canopen

from gateway.eds.parse import EdsError, EdsProblem, EdsText, check_text, read_text
from gateway.objref import ObjRef

__all__ = ["EdsError", "EdsFile", "EdsProblem", "import_od_strict", "load_eds"]


@dataclass(frozen=True)
class EdsFile:
    """A checked EDS/DCF: its path, its sections with their lines, canopen's dictionary."""

    path: Path
    text: EdsText
    od: canopen.ObjectDictionary

    @property
    def is_dcf(self) -> bool:
        return self.path.suffix.lower() == ".dcf"

    def var(self, obj: ObjRef) -> canopen.objectdictionary.ODVariable | None:
        return od_var(self.od, obj)

    def line_of(self, obj: ObjRef) -> int:
        entry = self.od.get(obj.index)
        if isinstance(entry, canopen.objectdictionary.ODVariable):
            return self.text.line_of(obj.index)
        return self.text.line_of(obj.index, obj.sub) or self.text.line_of(obj.index)

    @property
    def product_name(self) -> str:
        sec = self.text.section("DeviceInfo")
        return (sec.get("ProductName") if sec else None) or self.path.stem


def od_var(od: canopen.ObjectDictionary, obj: ObjRef) -> canopen.objectdictionary.ODVariable | None:
    """The variable at ``obj`` (a VAR at sub 0 or a sub-object), None when absent."""
    try:
        entry = od[obj.index]
    except KeyError:
        return None
    if isinstance(entry, canopen.objectdictionary.ODVariable):
        return entry if obj.sub == 0 else None
    try:
        return entry[obj.sub]
    except KeyError:
        return None


def import_od_strict(text: str, path: Path, node_id: int | None = None) -> canopen.ObjectDictionary:
    """canopen's ``import_od`` on already checked text; its warnings become an EdsError."""
    log = logging.getLogger("canopen.objectdictionary.eds")
    records: list[str] = []

    class _Catch(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if record.levelno >= logging.WARNING:
                records.append(record.getMessage())

    h = _Catch()
    log.addHandler(h)
    fp = io.StringIO(text)
    fp.name = str(path)  # type: ignore[attr-defined]  # import_od picks the format by suffix
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            od = canopen.import_od(fp, node_id)
    except Exception as exc:  # canopen raises many kinds on a bad file
        raise EdsError([f"{path}: cannot be parsed: {exc}"]) from exc
    finally:
        log.removeHandler(h)
    problems = records + [str(w.message) for w in caught]
    if problems:
        raise EdsError([f"{path}: {p}" for p in problems])
    return od


@functools.lru_cache(maxsize=64)
def _load(path: Path, _mtime: float) -> EdsFile:
    try:
        text = read_text(path)
    except OSError as exc:
        raise EdsError([f"{path}: cannot read: {exc.strerror or exc}"]) from None
    checked = check_text(text, str(path))
    od = import_od_strict(text, path)
    return EdsFile(path, checked, od)


def load_eds(path: str | Path) -> EdsFile:
    """Check and read an EDS or DCF (cached per file and modification time)."""
    p = Path(path).resolve()
    if p.suffix.lower() not in (".eds", ".dcf"):
        raise EdsError([f"{p}: an EDS must end in .eds (a DCF in .dcf)"])
    try:
        mtime = p.stat().st_mtime
    except OSError:
        raise EdsError([f"{p}: file does not exist"]) from None
    return _load(p, mtime)
