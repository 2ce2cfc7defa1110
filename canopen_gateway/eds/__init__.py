"""EDS / DCF knowledge: a tolerant loader, its lint, the PDOs an EDS describes, derived signals.

``load_eds(path)`` reads a file as CiA 306 and the common tools do (``parse`` splits the text,
``build`` makes canopen's ``ObjectDictionary`` with the standard's defaults): it refuses only a
file it cannot read at all. Every deviation from CiA 306 is a warning with file, line and
section (``EdsFile.warnings``). ``lint(eds)`` adds what the file's own enabled PDOs would do
in the gateway (``pdos.mapping_findings``): an error where the gateway would decode a PDO
wrongly (an object the file does not define, more than 64 bits), a warning where a signal is
skipped, and a warning for each COB-ID written absolute that is another node's pre-defined one
(``file_cob_ids``: ``0x181`` in a file for any node but node 1, a DCF's own NodeID excepted). ``pdos.eds_pdos`` lists the TPDOs and RPDOs of the dictionary (communication and
mapping objects 1400h-1BFFh, ``$NODEID`` resolved), ``pdos.unique_names`` names the mapped
objects (ParameterName slugs, unique per node), ``show.render`` prints a dictionary and its PDOs.

Imports: its own modules (parse, build, pdos, file_cob_ids), canopen, canopen_gateway.canopen.objref and the standard
library (difflib: the near names of a missing file). Nothing else of the gateway (the profile loader imports this package, not the other
way round).
"""

from __future__ import annotations

import difflib
import functools
from dataclasses import dataclass
from pathlib import Path

import canopen

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.build import build_dictionary
from canopen_gateway.eds.file_cob_ids import dcf_node_id, foreign_cob_id_problems
from canopen_gateway.eds.parse import EdsError, EdsProblem, EdsText, read_sections, read_text
from canopen_gateway.eds.pdos import PdoFinding, eds_pdo_findings

__all__ = ["EdsError", "EdsFile", "EdsProblem", "Lint", "dictionary_for_node", "lint", "load_eds", "near_names"]


@dataclass(frozen=True)
class EdsFile:
    """A loaded EDS/DCF: its path, its sections with their lines, canopen's dictionary and the
    warnings of reading it (deviations from CiA 306, each with file, line and section)."""

    path: Path
    text: EdsText
    od: canopen.ObjectDictionary
    warnings: tuple[EdsProblem, ...] = ()

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

    def problem(self, obj: ObjRef, message: str) -> EdsProblem:
        """``message`` at the section of ``obj`` (the object's when it has no sub-section)."""
        line = self.text.line_of(obj.index, obj.sub)
        if line:
            return EdsProblem(str(self.path), line, self.text.section_name(obj.index, obj.sub), message)
        line = self.text.line_of(obj.index)
        return EdsProblem(str(self.path), line, self.text.section_name(obj.index) if line else "", message)

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
    return entry.subindices.get(obj.sub)


@functools.lru_cache(maxsize=64)
def _load(path: Path, _mtime: float, _size: int) -> EdsFile:
    try:
        text = read_text(path)
    except OSError as exc:
        raise EdsError([f"{path}: cannot read: {exc.strerror or exc}"]) from None
    sections, warnings = read_sections(text, str(path))
    od, more = build_dictionary(sections, str(path))
    return EdsFile(path, EdsText(str(path), sections), od, tuple(sorted(warnings + more, key=lambda p: p.line)))


def load_eds(path: str | Path) -> EdsFile:
    """Read an EDS or DCF (cached per file, modification time and size); raises EdsError only
    for a file that cannot be read."""
    p = Path(path).resolve()
    if p.suffix.lower() not in (".eds", ".dcf"):
        raise EdsError([f"{p}: an EDS must end in .eds (a DCF in .dcf)"])
    try:
        st = p.stat()
    except OSError:
        raise EdsError([f"{p}: file does not exist{near_names(p, ('.eds', '.dcf'))}"]) from None
    if not p.is_file():
        raise EdsError([f"{p}: not a file"])
    return _load(p, st.st_mtime, st.st_size)


def near_names(path: Path, suffixes: tuple[str, ...]) -> str:
    """What a missing file's folder holds: ``; did you mean io401.eds?`` for near names (any
    case), else the files of ``suffixes`` there (at most 8), or that the folder is missing."""
    folder = path.parent
    try:
        names = sorted(f.name for f in folder.iterdir() if f.suffix.lower() in suffixes and f.is_file())
    except OSError:
        return f" (nor does its folder {folder})"
    if not names:
        return f" (no {' or '.join(suffixes)} file in {folder})"
    lowered = {n.lower(): n for n in names}
    near = [lowered[n] for n in difflib.get_close_matches(path.name.lower(), list(lowered), n=3, cutoff=0.6)]
    if near:
        return "; did you mean " + " or ".join(near) + "?"
    listed = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
    return f" (in {folder}: {listed})"


def dictionary_for_node(path: str | Path, node_id: int | None) -> canopen.ObjectDictionary:
    """The dictionary of a file with ``$NODEID`` values resolved for ``node_id``."""
    eds = load_eds(path)
    od, _ = build_dictionary(eds.text.sections, str(eds.path), node_id)
    return od


@dataclass(frozen=True)
class Lint:
    """``eds lint``: errors (the gateway cannot use the file as it stands) and warnings."""

    errors: tuple[EdsProblem, ...]
    warnings: tuple[EdsProblem, ...]

    @property
    def exit_code(self) -> int:
        return 2 if self.errors else 1 if self.warnings else 0


def finding_problem(eds: EdsFile, f: PdoFinding) -> EdsProblem:
    return eds.problem(f.obj, f.message)


def lint(eds: EdsFile) -> Lint:
    """The file's warnings plus the findings of its enabled PDOs and its absolute COB-IDs of
    another node (see the module docstring)."""
    findings = eds_pdo_findings(eds.od)
    errors = tuple(finding_problem(eds, f) for f in findings if f.fatal)
    pdo_warnings = [finding_problem(eds, f) for f in findings if not f.fatal]
    own = dcf_node_id(eds)
    cob_warnings = foreign_cob_id_problems(eds, own[0] if own is not None else None)
    every = [*eds.warnings, *pdo_warnings, *cob_warnings]
    return Lint(errors, tuple(sorted(every, key=lambda p: p.line)))
