"""A node's DCF (CiA 306 device configuration file) as the gateway configures it: the device's
EDS (or DCF) as written, with ``[DeviceComissioning]`` (node id, name, bit rate in kbit/s, the
network's number and name) and
the ``ParameterValue`` of every object its boot configuration writes (``boot_steps``: 1017h or
guarding 100Ch/100Dh, the PDO communication and mapping objects the profile and the node's
``tpdo:``/``rpdo:`` set, the profile's ``boot.sdo`` and the node's ``sdo:``), each the value the
device holds once the boot steps ran (the last write of an object wins: a PDO's COB-ID ends
valid). What Lely's dcfgen or a configuration tool writes for a node, for a second master, a
commissioning tool or the plant's documentation.

The EDS text is kept line for line (its comments, its order, its own ``ParameterValue`` of the
objects the gateway does not write); a written object whose section the file does not have (a
``CompactSubObj`` array) gets a section of its own at the end. Values are written as CiA 306
reads them: unsigned numbers in hex (``0x182``), signed ones in decimal, text as it is; COB-IDs
absolute (the DCF is for this node id). Pure: text in, text out.

Imports: canopen_gateway.canopen.cia301 (TYPE_NAMES), canopen_gateway.canopen.objref, canopen_gateway.device.boot_steps
(ConfigStep) and the standard library.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from canopen_gateway.canopen.cia301 import TYPE_NAMES
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.device.boot_steps import ConfigStep

_SECTION = re.compile(r"^\s*\[([^\]]*)\]")
_OBJECT_SECTION = re.compile(r"^([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]{1,2}))?$", re.IGNORECASE)
_KEY = re.compile(r"^\s*([^=;#\s][^=]*?)\s*=")
#: CiA 306 4.6.4: the section the commissioning values live in (spelt so in the standard)
COMMISSIONING = "DeviceComissioning"


@dataclass(frozen=True)
class Commissioning:
    """What ``[DeviceComissioning]`` says of the node on its network."""

    node_id: int
    node_name: str
    bitrate_kbps: int
    network_name: str
    #: the network's number (CiA 309-3's net: 1.. in configured order; 1 with one network)
    net_number: int = 1


def final_values(steps: Iterable[ConfigStep]) -> dict[ObjRef, ConfigStep]:
    """Each object the steps write, with the step that writes it last (its value in the device
    once the boot configuration ran), in the order of first writing."""
    out: dict[ObjRef, ConfigStep] = {}
    for step in steps:
        out[step.object] = step
    return out


def parameter_value(step: ConfigStep) -> str:
    """The value as CiA 306 writes it: unsigned in hex, signed in decimal, text as it is."""
    v: Any = step.value
    if step.type in ("string",):
        return str(v)
    if step.type == "bytes":
        return str(v).encode("latin-1").hex().upper()
    if isinstance(v, float) or step.type.startswith("float"):
        return repr(float(v))
    if step.type.startswith("int") or int(v) < 0:
        return str(int(v))
    return f"0x{int(v):X}"


@dataclass
class _Section:
    name: str
    start: int  # the line of its [header]
    end: int  # one past its last key line (trailing blank and comment lines excluded)


def _sections(lines: list[str]) -> list[_Section]:
    out: list[_Section] = []
    for i, line in enumerate(lines):
        m = _SECTION.match(line)
        if m:
            out.append(_Section(m.group(1).strip(), i, i + 1))
        elif out and _KEY.match(line):
            out[-1].end = i + 1
    return out


def _object_of(name: str, subs: set[int]) -> ObjRef | None:
    """The object a section describes: ``1800sub1`` is 1800h:01; ``1017`` is 1017h:00 when the
    file has no ``1017subN`` sections (a VAR), else the record's header (no value)."""
    m = _OBJECT_SECTION.match(name)
    if m is None:
        return None
    index = int(m.group(1), 16)
    if m.group(2) is not None:
        return ObjRef(index, int(m.group(2), 16))
    return None if index in subs else ObjRef(index, 0)


def write_dcf(eds_text: str, eds_name: str, steps: Iterable[ConfigStep], who: Commissioning, od: Any) -> str:
    """The DCF of one node: ``eds_text`` (the device's EDS or DCF, named ``eds_name``) with the
    node's commissioning values and the ParameterValue of every object ``steps`` write; ``od``
    (canopen's ObjectDictionary of the file) names and types an object the file describes
    compactly."""
    newline = "\r\n" if "\r\n" in eds_text else "\n"
    lines = eds_text.splitlines()
    values = final_values(steps)
    sections = _sections(lines)
    with_subs = {
        int(m.group(1), 16)
        for s in sections
        if (m := _OBJECT_SECTION.match(s.name)) is not None and m.group(2) is not None
    }
    inserts: dict[int, list[str]] = {}  # line -> lines to put before it
    drop: set[int] = set()
    done: set[ObjRef] = set()
    for s in sections:
        if s.name.lower() == COMMISSIONING.lower():
            drop.update(range(s.start, _block_end(lines, s, sections)))
            continue
        if s.name.lower() == "fileinfo":  # CiA 306 4.5.1: this file's name, the EDS it came from
            inserts.setdefault(s.end, []).extend([f"FileName={who.node_name}.dcf", f"LastEDS={eds_name}"])
            drop.update([*_key_lines(lines, s, "LastEDS"), *_key_lines(lines, s, "FileName")])
            continue
        obj = _object_of(s.name, with_subs)
        if obj is None or obj not in values or obj in done:
            continue
        done.add(obj)
        drop.update(_key_lines(lines, s, "ParameterValue"))
        inserts.setdefault(s.end, []).append(f"ParameterValue={parameter_value(values[obj])}")
    out: list[str] = []
    for i, line in enumerate(lines):
        out.extend(inserts.get(i, []))
        if i not in drop:
            out.append(line)
    out.extend(inserts.get(len(lines), []))
    for obj, step in values.items():
        if obj not in done:
            out += ["", *_compact_section(obj, step, od)]
    out += ["", f"[{COMMISSIONING}]", f"NodeID={who.node_id}", f"NodeName={who.node_name}",
            f"Baudrate={who.bitrate_kbps}", f"NetNumber={who.net_number}", f"NetworkName={who.network_name}",
            "CANopenManager=0"]  # fmt: skip
    return newline.join(out) + newline


def _key_lines(lines: list[str], s: _Section, key: str) -> list[int]:
    return [
        i
        for i in range(s.start + 1, s.end)
        if (m := _KEY.match(lines[i])) is not None and m.group(1).lower() == key.lower()
    ]


def _block_end(lines: list[str], s: _Section, sections: list[_Section]) -> int:
    """Where the section's text ends: the next section's header (its blank lines go too)."""
    later = [t.start for t in sections if t.start > s.start]
    return later[0] if later else len(lines)


def _compact_section(obj: ObjRef, step: ConfigStep, od: Any) -> list[str]:
    """A section of its own for a sub-object the file describes compactly (CiA 306 4.5.2.3,
    CompactSubObj): its name, type and access from the dictionary, and the value."""
    var = od.get_variable(obj.index, obj.sub) if od is not None else None
    name = getattr(var, "name", None) or f"{step.description or obj}"
    data_type = getattr(var, "data_type", None) or _type_code(step.type)
    access = getattr(var, "access_type", None) or "rw"
    return [
        f"[{obj.index:04X}sub{obj.sub:X}]",
        f"ParameterName={name}",
        "ObjectType=0x7",
        f"DataType=0x{data_type:04X}",
        f"AccessType={access}",
        "PDOMapping=0",
        f"ParameterValue={parameter_value(step)}",
    ]


def _type_code(type_name: str) -> int:
    for code, name in TYPE_NAMES.items():
        if name == type_name and code is not None:
            return code
    return 0x0007  # UNSIGNED32
