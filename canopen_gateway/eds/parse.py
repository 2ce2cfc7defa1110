"""Reading EDS and DCF text (CiA 306) tolerantly, keeping the line of every section and key.

``read_sections(text, path)`` splits the INI text into sections and keys (names case-insensitive,
values with ``;`` comments removed) and never fails: what it cannot read is skipped and named in
a warning (an :class:`EdsProblem`: file, line, section, message). A line outside any section, a
line that is not ``key=value``, a header with text after its ``]``, a duplicate section or key
(the first one counts) are such warnings; two spellings of one sub-section (``[1A00sub1]``,
``[1A00sub01]``) are two sections here, and ``build`` keeps the first. ``parse_int`` reads a
CiA 306 4.6.3 number in every notation the standard and the common tools use: decimal, ``0x``
hex, octal with a leading 0, ``$NODEID+<n>`` / ``<n>+$NODEID``; ``parse_real`` a REAL in
decimal or as its IEEE 754 bit pattern in hex (``0x40490FDB`` = 3.1415927).

Bounds (a file past one is refused in one line, before it costs memory: an 18 MB file of
60,000 objects with ``CompactSubObj=254`` would make 15 million sub-objects, about 11 GB):
``MAX_EDS_BYTES`` of text, ``MAX_SECTIONS`` sections; ``build`` bounds the objects and the
sub-objects they make (``MAX_OBJECTS``, ``MAX_SUB_OBJECTS``). Real device files are far
below: the largest of the corpus the tests read is 0.7 MB with about 2,000 sub-objects.

Imports: the standard library only.
"""

from __future__ import annotations

import re
import struct
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

# CiA 306 4.6.3: ObjectType codes.
OBJECT_TYPES = {0x0: "NULL", 0x2: "DOMAIN", 0x5: "DEFTYPE", 0x6: "DEFSTRUCT", 0x7: "VAR",
                0x8: "ARRAY", 0x9: "RECORD"}  # fmt: skip
ACCESS_TYPES = {"ro", "wo", "rw", "rwr", "rww", "const"}

#: what a device description may be (see the module docstring): a few MB, some thousands of
#: objects (CiA 301 allows 65,536 indexes; no device fills them)
MAX_EDS_BYTES = 8 * 1024 * 1024
MAX_OBJECTS = 16_384
MAX_SUB_OBJECTS = 65_536
MAX_SECTIONS = MAX_OBJECTS + MAX_SUB_OBJECTS + 1024

_NODEID = re.compile(r"\$NODEID", re.I)
_INT = re.compile(r"^[+-]?(0x[0-9a-f]+|[0-9]+)$", re.I)


@dataclass(frozen=True)
class EdsProblem:
    """One deviation of a file, where it is: ``file:line: [section]: message``."""

    path: str
    line: int
    section: str
    message: str

    def __str__(self) -> str:
        where = f"[{self.section}]" if self.section else "(no section)"
        return f"{self.path}:{self.line}: {where}: {self.message}"


class EdsError(Exception):
    """An EDS/DCF the gateway cannot use; ``problems`` has one line per problem."""

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

    def _object_section(self, index: int, sub: int | None) -> Section | None:
        """The section of an object or sub-object; of two spellings of one sub-section
        (``[1A00sub1]``, ``[1A00sub01]``) the first in the file, the one that counts."""
        if sub is None:
            return self.section(f"{index:04X}")
        found = [s for n in {f"{sub:X}", f"{sub:02X}"} if (s := self.section(f"{index:04X}sub{n}"))]
        return min(found, key=lambda s: s.line, default=None)

    def line_of(self, index: int, sub: int | None = None) -> int:
        s = self._object_section(index, sub)
        return s.line if s is not None else 0

    def section_name(self, index: int, sub: int | None = None) -> str:
        s = self._object_section(index, sub)
        return s.name if s is not None else (f"{index:04X}" if sub is None else f"{index:04X}sub{sub:X}")


def parse_int(text: str) -> tuple[int, bool]:
    """A CiA 306 4.6.3 integer: ``(value, relative)``; ``relative`` when ``$NODEID`` is one of
    its terms (the value is then the rest: ``$NODEID+0x180`` -> ``(0x180, True)``).

    Decimal, ``0x`` hex, octal with a leading 0 (``010`` = 8), a sign; raises ValueError."""
    s = text.strip().replace(" ", "").replace("\t", "")
    relative = False
    if _NODEID.search(s):
        relative = True
        terms = [t for t in _NODEID.sub("", s).split("+") if t]
        return sum(_int(t, text) for t in terms), relative
    return _int(s, text), relative


def _int(s: str, text: str) -> int:
    if not _INT.match(s):
        raise ValueError(f"{text.strip()!r} is not a number")
    neg = s.startswith("-")
    body = s.lstrip("+-")
    if body[:2].lower() == "0x":
        v = int(body, 16)
    elif len(body) > 1 and body.startswith("0"):
        if any(c in "89" for c in body):
            raise ValueError(f"{text.strip()!r} is not a number (a leading 0 means octal)")
        v = int(body, 8)
    else:
        v = int(body)
    return -v if neg else v


def parse_real(text: str, bits: int) -> float:
    """A REAL32 (``bits`` 32) or REAL64 value: decimal (``1.5``, ``1e3``) or hex, read as the
    IEEE 754 bit pattern as Lely and CANopenNode write it (``0x3F800000`` = 1.0)."""
    s = text.strip()
    if s[:2].lower() == "0x":
        raw = int(s, 16)
        if raw >= 1 << bits:
            raise ValueError(f"{s!r} has more than {bits} bits")
        fmt = "<f" if bits == 32 else "<d"
        return float(struct.unpack(fmt, raw.to_bytes(bits // 8, "little"))[0])
    try:
        return float(s)
    except ValueError:
        raise ValueError(f"{s!r} is not a number") from None


def read_sections(text: str, path: str) -> tuple[dict[str, Section], list[EdsProblem]]:
    """The sections of ``text`` and a warning for every line that is not read as written."""
    warnings: list[EdsProblem] = []
    sections: dict[str, Section] = {}
    current: Section | None = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line[0] in ";#":
            continue
        if line.startswith("["):
            end = line.find("]")
            if end < 0:
                warnings.append(EdsProblem(path, lineno, "", f"section header {line!r} has no ']': its keys are ignored"))  # fmt: skip
                current = None
                continue
            name = line[1:end].strip()
            rest = line[end + 1 :].strip()
            if rest and rest[0] != ";":
                warnings.append(EdsProblem(path, lineno, name, f"text after the section header ignored: {rest!r}"))  # fmt: skip
            key = name.lower()
            if key in sections:
                first = sections[key].line
                warnings.append(EdsProblem(path, lineno, name, f"duplicate section (first at line {first}): its new keys are added"))  # fmt: skip
                current = sections[key]
                continue
            if len(sections) >= MAX_SECTIONS:
                raise EdsError([f"{path}:{lineno}: more than {MAX_SECTIONS} sections: not a device "
                                "description the gateway loads (a device has some thousands)"])  # fmt: skip
            current = Section(name, lineno)
            sections[key] = current
            continue
        if "=" not in line:
            sec = current.name if current else ""
            warnings.append(EdsProblem(path, lineno, sec, f"line {line!r} is not 'key=value': ignored"))  # fmt: skip
            continue
        if current is None:
            warnings.append(EdsProblem(path, lineno, "", f"{line!r} before any section: ignored"))
            continue
        key, value = line.split("=", 1)
        value = value.split(";", 1)[0].strip() if ";" in value else value.strip()
        k = key.strip().lower()
        if k in current.keys:
            warnings.append(
                EdsProblem(path, lineno, current.name, f"duplicate key {key.strip()} (first at line {current.keys[k][1]}): ignored")  # fmt: skip
            )
            continue
        current.keys[k] = (value, lineno)
    return sections, warnings


def read_text(path: Path) -> str:
    """The file's text: UTF-8 (ASCII is a subset); Latin-1 when it is not valid UTF-8.
    EdsError for a file over ``MAX_EDS_BYTES`` (it is not read)."""
    size = path.stat().st_size
    if size > MAX_EDS_BYTES:
        raise EdsError([f"{path}: {size} bytes, more than {MAX_EDS_BYTES} (8 MiB): not a device "
                        "description the gateway loads (real ones are below 1 MB)"])  # fmt: skip
    data = path.read_bytes()
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")
