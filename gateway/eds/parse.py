"""Strict reading of EDS and DCF files (CiA 306), in the spirit of Lely's ``dcfchk``.

``read_eds_text(text, path)`` parses the INI text itself, keeping the line of every section and
key, and checks what canopen's parser accepts in silence: a line outside a section, a
duplicate section or key, a section name that is neither a known one nor an object
(``[6401sbu2]``), an object without or with a wrong ``ObjectType`` / ``DataType`` /
``AccessType`` / ``ParameterName``, a malformed number (``DefaultValue=0x6401011O``,
``SubNumber=0x1l``), a ``SubNumber`` that does not match the sub-sections, a sub-section
without its object, an object list (``[MandatoryObjects]`` ...) naming a missing section. Every
problem is one :class:`EdsProblem` with the file, line and section; ``EdsError`` carries them
all. Nothing is dropped: what this module accepts, canopen's ``import_od`` reads the same way.

Imports: the standard library only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

# CiA 301 table 44 / CiA 306 4.6.3: data types an object or sub-object may have.
DATA_TYPES: dict[int, str] = {
    0x0001: "BOOLEAN",
    0x0002: "INTEGER8",
    0x0003: "INTEGER16",
    0x0004: "INTEGER32",
    0x0005: "UNSIGNED8",
    0x0006: "UNSIGNED16",
    0x0007: "UNSIGNED32",
    0x0008: "REAL32",
    0x0009: "VISIBLE_STRING",
    0x000A: "OCTET_STRING",
    0x000B: "UNICODE_STRING",
    0x000C: "TIME_OF_DAY",
    0x000D: "TIME_DIFFERENCE",
    0x000F: "DOMAIN",
    0x0010: "INTEGER24",
    0x0011: "REAL64",
    0x0012: "INTEGER40",
    0x0013: "INTEGER48",
    0x0014: "INTEGER56",
    0x0015: "INTEGER64",
    0x0016: "UNSIGNED24",
    0x0018: "UNSIGNED40",
    0x0019: "UNSIGNED48",
    0x001A: "UNSIGNED56",
    0x001B: "UNSIGNED64",
}
_TEXT_TYPES = {0x0009, 0x000A, 0x000B, 0x000F}
_FLOAT_TYPES = {0x0008, 0x0011}

# CiA 306 4.6.3: ObjectType codes.
OBJECT_TYPES = {0x0: "NULL", 0x2: "DOMAIN", 0x5: "DEFTYPE", 0x6: "DEFSTRUCT", 0x7: "VAR",
                0x8: "ARRAY", 0x9: "RECORD"}  # fmt: skip
ACCESS_TYPES = {"ro", "wo", "rw", "rwr", "rww", "const"}

#: Sections that are not objects (CiA 306 / 306-3 for DCF, case-insensitive).
KNOWN_SECTIONS = {
    "fileinfo", "deviceinfo", "dummyusage", "comments", "mandatoryobjects", "optionalobjects",
    "manufacturerobjects", "devicecomissioning", "devicecommissioning", "tools",
    "supportedmodules", "connectedmodules", "dynamicchannels",
}  # fmt: skip
_KNOWN_PATTERNS = [
    re.compile(r"^tool\d+$", re.I),
    re.compile(r"^m\d+(moduleinfo|fixedobjects|subextends|comments)$", re.I),
    re.compile(r"^m\d+subext[0-9a-f]{4}$", re.I),
    re.compile(r"^m\d+fixed[0-9a-f]{4}(sub[0-9a-f]{1,2})?$", re.I),
]
_OBJ_SECTION = re.compile(r"^([0-9A-Fa-f]{4})$")
_SUB_SECTION = re.compile(r"^([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})$", re.I)
_AUX_SECTION = re.compile(r"^([0-9A-Fa-f]{4})(Name|Value|Denotation)$", re.I)
_OBJECT_LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")

_INT_RE = re.compile(r"^[+-]?(0x[0-9a-f]+|[0-9]+)$", re.I)
_NODEID_RE = re.compile(r"^\$nodeid\s*\+\s*(.+)$|^(.+?)\s*\+\s*\$nodeid$|^\$nodeid$", re.I)


@dataclass(frozen=True)
class EdsProblem:
    path: str
    line: int
    section: str
    message: str

    def __str__(self) -> str:
        where = f"[{self.section}]" if self.section else "(no section)"
        return f"{self.path}:{self.line}: {where}: {self.message}"


class EdsError(Exception):
    """An EDS/DCF that cannot be used; ``problems`` has one entry per problem."""

    def __init__(self, problems: list[EdsProblem] | list[str]):
        self.problems = [str(p) for p in problems]
        super().__init__("\n".join(self.problems))


@dataclass
class Section:
    name: str
    line: int
    keys: dict[str, tuple[str, int]] = field(default_factory=dict)  # lower key -> (value, line)

    def get(self, key: str) -> str | None:
        v = self.keys.get(key.lower())
        return v[0] if v is not None else None

    def line_of(self, key: str) -> int:
        v = self.keys.get(key.lower())
        return v[1] if v is not None else self.line


@dataclass
class EdsText:
    """The sections of one file with their lines (keys case-insensitive, names as written)."""

    path: str
    sections: dict[str, Section]  # lower name -> section

    def section(self, name: str) -> Section | None:
        return self.sections.get(name.lower())

    def line_of(self, index: int, sub: int | None = None) -> int:
        name = f"{index:04X}" if sub is None else f"{index:04X}sub{sub:X}"
        s = self.section(name)
        return s.line if s is not None else 0


def parse_number(text: str, *, node_id_allowed: bool = False) -> int:
    """CiA 306 4.6.3 integer: decimal or ``0x`` hex, optionally ``$NODEID+<n>``; raises
    ValueError naming the text. (Octal with a leading 0 is refused: canopen does not read it.)"""
    s = text.strip()
    if node_id_allowed:
        m = _NODEID_RE.match(s)
        if m:
            rest = m.group(1) or m.group(2)
            return parse_number(rest) if rest else 0
    if not _INT_RE.match(s):
        raise ValueError(f"{text!r} is not a number")
    body = s.lstrip("+-")
    if body.lower().startswith("0x"):
        v = int(body, 16)
    elif len(body) > 1 and body.startswith("0"):
        raise ValueError(f"{text!r}: a leading 0 (octal) is not supported; write decimal or 0x hex")
    else:
        v = int(body)
    return -v if s.startswith("-") else v


def _read_sections(text: str, path: str, problems: list[EdsProblem]) -> dict[str, Section]:
    sections: dict[str, Section] = {}
    current: Section | None = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith(";") or line.startswith("#"):
            continue
        if line.startswith("["):
            if not line.endswith("]"):
                problems.append(EdsProblem(path, lineno, "", f"section header {line!r} has no ']'"))
                current = None
                continue
            name = line[1:-1].strip()
            if name.lower() in sections:
                first = sections[name.lower()].line
                problems.append(EdsProblem(path, lineno, name, f"duplicate section (first at line {first})"))  # fmt: skip
                current = sections[name.lower()]
                continue
            current = Section(name, lineno)
            sections[name.lower()] = current
            continue
        if "=" not in line:
            sec = current.name if current else ""
            problems.append(EdsProblem(path, lineno, sec, f"line {line!r} is not 'key=value'"))
            continue
        if current is None:
            problems.append(EdsProblem(path, lineno, "", f"{line!r} before any section"))
            continue
        key, value = line.split("=", 1)
        value = value.split(";", 1)[0].strip() if ";" in value else value.strip()
        k = key.strip().lower()
        if k in current.keys:
            problems.append(
                EdsProblem(path, lineno, current.name, f"duplicate key {key.strip()} (first at line {current.keys[k][1]})")  # fmt: skip
            )
            continue
        current.keys[k] = (value, lineno)
    return sections


def _check_value(
    sec: Section, key: str, data_type: int | None, path: str, problems: list[EdsProblem]
) -> None:
    raw = sec.get(key)
    if raw is None or raw == "" or data_type is None:
        return
    if data_type in _TEXT_TYPES:
        return
    line = sec.line_of(key)
    if data_type in _FLOAT_TYPES:
        try:
            float(raw)
        except ValueError:
            problems.append(EdsProblem(path, line, sec.name, f"{key}={raw}: not a number"))
        return
    try:
        parse_number(raw, node_id_allowed=True)
    except ValueError as exc:
        problems.append(EdsProblem(path, line, sec.name, f"{key}={raw}: {exc}"))


def _check_var(sec: Section, path: str, problems: list[EdsProblem], *, dcf: bool) -> None:
    """The keys of a VAR object or a sub-object (CiA 306 4.6.3)."""
    dt_raw = sec.get("DataType")
    data_type: int | None = None
    if dt_raw is None:
        problems.append(EdsProblem(path, sec.line, sec.name, "DataType is missing"))
    else:
        try:
            data_type = parse_number(dt_raw)
        except ValueError as exc:
            problems.append(EdsProblem(path, sec.line_of("DataType"), sec.name, f"DataType: {exc}"))
        else:
            if data_type not in DATA_TYPES:
                problems.append(
                    EdsProblem(path, sec.line_of("DataType"), sec.name,
                               f"DataType=0x{data_type:04X} is not a CiA 301 data type")  # fmt: skip
                )
                data_type = None
    acc = sec.get("AccessType")
    if acc is None:
        problems.append(EdsProblem(path, sec.line, sec.name, "AccessType is missing"))
    elif acc.strip().lower() not in ACCESS_TYPES:
        problems.append(
            EdsProblem(path, sec.line_of("AccessType"), sec.name,
                       f"AccessType={acc}: must be one of {', '.join(sorted(ACCESS_TYPES))}")  # fmt: skip
        )
    pm = sec.get("PDOMapping")
    if pm is not None and pm.strip() not in ("0", "1"):
        problems.append(EdsProblem(path, sec.line_of("PDOMapping"), sec.name, f"PDOMapping={pm}: must be 0 or 1"))  # fmt: skip
    for key in ("DefaultValue", "LowLimit", "HighLimit") + (("ParameterValue",) if dcf else ()):
        _check_value(sec, key, data_type, path, problems)


def _check_object_type(sec: Section, path: str, problems: list[EdsProblem]) -> int | None:
    raw = sec.get("ObjectType")
    if raw is None:
        problems.append(EdsProblem(path, sec.line, sec.name, "ObjectType is missing"))
        return None
    try:
        ot = parse_number(raw)
    except ValueError as exc:
        problems.append(EdsProblem(path, sec.line_of("ObjectType"), sec.name, f"ObjectType: {exc}"))
        return None
    if ot not in OBJECT_TYPES:
        allowed = ", ".join(f"0x{k:X} {v}" for k, v in OBJECT_TYPES.items())
        problems.append(EdsProblem(path, sec.line_of("ObjectType"), sec.name, f"ObjectType={raw}: must be one of {allowed}"))  # fmt: skip
        return None
    return ot


def check_text(text: str, path: str) -> EdsText:
    """Parse and check the text of an EDS/DCF; raise EdsError with every problem found."""
    problems: list[EdsProblem] = []
    sections = _read_sections(text, path, problems)
    dcf = path.lower().endswith(".dcf")
    objects: dict[int, Section] = {}
    subs: dict[int, list[Section]] = {}
    for sec in sections.values():
        name = sec.name
        if _OBJ_SECTION.match(name):
            objects[int(name, 16)] = sec
        elif m := _SUB_SECTION.match(name):
            subs.setdefault(int(m.group(1), 16), []).append(sec)
        elif _AUX_SECTION.match(name):
            continue
        elif name.lower() in KNOWN_SECTIONS or any(p.match(name) for p in _KNOWN_PATTERNS):
            continue
        else:
            problems.append(
                EdsProblem(path, sec.line, name,
                           "unknown section name: neither an object ([6401], [6401sub2]) nor a "
                           "CiA 306 section ([FileInfo], [DeviceInfo], [MandatoryObjects], ...)")  # fmt: skip
            )
    dummy = sections.get("dummyusage")
    if dummy is not None:
        for i in range(1, 8):  # canopen reads Dummy0001..Dummy0007, each 0 or 1
            v = dummy.get(f"Dummy{i:04X}")
            if v is None:
                problems.append(EdsProblem(path, dummy.line, dummy.name, f"Dummy{i:04X} is missing (0 or 1)"))  # fmt: skip
            elif v.strip() not in ("0", "1"):
                problems.append(EdsProblem(path, dummy.line_of(f"Dummy{i:04X}"), dummy.name, f"Dummy{i:04X}={v}: must be 0 or 1"))  # fmt: skip
    if "deviceinfo" not in sections:
        problems.append(EdsProblem(path, 1, "DeviceInfo", "section [DeviceInfo] is missing"))
    for index, sec in sorted(objects.items()):
        pn = sec.get("ParameterName")
        if pn is None or not pn.strip():
            problems.append(EdsProblem(path, sec.line, sec.name, "ParameterName is missing or empty"))  # fmt: skip
        ot = _check_object_type(sec, path, problems)
        own_subs = subs.get(index, [])
        if ot in (0x7, 0x2, 0x5):
            if own_subs:
                problems.append(EdsProblem(path, own_subs[0].line, own_subs[0].name,
                                           f"sub-section of [{sec.name}], which is not an ARRAY or RECORD"))  # fmt: skip
            if ot == 0x7:
                _check_var(sec, path, problems, dcf=dcf)
        elif ot in (0x8, 0x9):
            compact = sec.get("CompactSubObj")
            sn = sec.get("SubNumber")
            if compact is not None:
                try:
                    parse_number(compact)
                except ValueError as exc:
                    problems.append(EdsProblem(path, sec.line_of("CompactSubObj"), sec.name, f"CompactSubObj: {exc}"))  # fmt: skip
                _check_var(sec, path, problems, dcf=dcf)
            elif sn is None:
                problems.append(EdsProblem(path, sec.line, sec.name, "SubNumber is missing (ARRAY/RECORD)"))  # fmt: skip
            else:
                try:
                    n = parse_number(sn)
                except ValueError as exc:
                    problems.append(EdsProblem(path, sec.line_of("SubNumber"), sec.name, f"SubNumber: {exc}"))  # fmt: skip
                else:
                    if n != len(own_subs):
                        found = ", ".join(f"[{s.name}]" for s in own_subs) or "none"
                        problems.append(
                            EdsProblem(path, sec.line_of("SubNumber"), sec.name,
                                       f"SubNumber={sn} but {len(own_subs)} sub-sections follow ({found})")  # fmt: skip
                        )
        for sub in own_subs:
            spn = sub.get("ParameterName")
            if spn is None or not spn.strip():
                problems.append(EdsProblem(path, sub.line, sub.name, "ParameterName is missing or empty"))  # fmt: skip
            sot = _check_object_type(sub, path, problems)
            if sot is not None and sot != 0x7:
                problems.append(EdsProblem(path, sub.line_of("ObjectType"), sub.name, "a sub-object must have ObjectType=0x7 (VAR)"))  # fmt: skip
            _check_var(sub, path, problems, dcf=dcf)
    for index, lst in subs.items():
        if index not in objects:
            for s in lst:
                problems.append(EdsProblem(path, s.line, s.name, f"sub-section without its object [{index:04X}]"))  # fmt: skip
    listed: set[int] = set()
    for list_name in _OBJECT_LISTS:
        sec = sections.get(list_name.lower())
        if sec is None:
            continue
        count_raw = sec.get("SupportedObjects")
        entries = {k: v for k, v in sec.keys.items() if k != "supportedobjects"}
        if count_raw is None:
            problems.append(EdsProblem(path, sec.line, sec.name, "SupportedObjects is missing"))
        else:
            try:
                count = parse_number(count_raw)
            except ValueError as exc:
                problems.append(EdsProblem(path, sec.line_of("SupportedObjects"), sec.name, f"SupportedObjects: {exc}"))  # fmt: skip
            else:
                if count != len(entries):
                    problems.append(EdsProblem(path, sec.line_of("SupportedObjects"), sec.name,
                                               f"SupportedObjects={count_raw} but {len(entries)} entries are listed"))  # fmt: skip
        for key, (value, line) in entries.items():
            try:
                parse_number(key)
                index = parse_number(value)
            except ValueError as exc:
                problems.append(EdsProblem(path, line, sec.name, f"{key}={value}: {exc}"))
                continue
            listed.add(index)
            if index not in objects:
                problems.append(EdsProblem(path, line, sec.name, f"object 0x{index:04X} is listed but has no section [{index:04X}]"))  # fmt: skip
    if listed:
        for index, sec in sorted(objects.items()):
            if index >= 0x1000 and index not in listed:
                problems.append(EdsProblem(path, sec.line, sec.name, "object is not listed in [MandatoryObjects], [OptionalObjects] or [ManufacturerObjects]"))  # fmt: skip
    if problems:
        problems.sort(key=lambda p: p.line)
        raise EdsError(problems)
    return EdsText(path, sections)


def read_text(path: Path) -> str:
    """The file's text: UTF-8 (ASCII is a subset); Latin-1 when it is not valid UTF-8."""
    data = path.read_bytes()
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")
