"""The COB-IDs an EDS/DCF sets, and the node id a DCF was written for.

A file gives a COB-ID either relative to the node id (``$NODEID+0x180``, CiA 306 4.6.3), right
at any node id, or absolute (``0x181``), right only at the node id it was written for: used at
node 5, an absolute ``1800sub1=0x181`` makes the device send its TPDO1 on node 1's pre-defined
COB-ID (CiA 301 7.3.3). ``file_cob_ids`` lists the COB-ID objects of a file (EMCY 1014h, the
default SDO server 1200h:01/02, RPDOs 1400h..15FFh:01, TPDOs 1800h..19FFh:01) as written (a
DCF's ParameterValue, else the DefaultValue); ``foreign_cob_ids`` the valid absolute ones that
are another node's pre-defined COB-ID; ``dcf_node_id`` the ``[DeviceComissioning] NodeID``.

Imports: canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref, canopen_gateway.eds.parse; canopen_gateway.eds (EdsFile) for types only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from canopen_gateway.canopen.cia301 import (
    COB_ID_EXTENDED,
    COB_ID_INVALID,
    COB_ID_MASK_11BIT,
    PDO_COMM_BASE,
    predefined_owner,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.parse import EdsProblem, parse_int

if TYPE_CHECKING:
    from canopen_gateway.eds import EdsFile

#: CiA 301 7.5.2.6 (1014h), 7.5.2.33 (1200h: 01h client -> server, 02h server -> client)
OBJ_EMCY_COB_ID = ObjRef(0x1014, 0x00)
OBJ_SDO_SERVER_RX = ObjRef(0x1200, 0x01)
OBJ_SDO_SERVER_TX = ObjRef(0x1200, 0x02)


@dataclass(frozen=True)
class FileCobId:
    """One COB-ID object of a file as written."""

    obj: ObjRef
    what: str  # "TPDO1", "EMCY", "SDO request"
    value: int  # as written; for a relative one the part besides $NODEID
    relative: bool
    section: str
    line: int

    @property
    def valid(self) -> bool:
        """Bit 31 clear and an 11-bit CAN-ID (bit 29 clear)."""
        return not self.value & (COB_ID_INVALID | COB_ID_EXTENDED)

    @property
    def cob_id(self) -> int:
        return self.value & COB_ID_MASK_11BIT

    def where(self, file: str) -> str:
        """``io.dcf [1800sub1] line 123``"""
        return f"{file} [{self.section}] line {self.line}"


def _cob_objects(eds: EdsFile) -> list[tuple[ObjRef, str]]:
    out = [(OBJ_EMCY_COB_ID, "EMCY"), (OBJ_SDO_SERVER_RX, "SDO request"), (OBJ_SDO_SERVER_TX, "SDO response")]  # fmt: skip
    for kind in ("rpdo", "tpdo"):
        base = PDO_COMM_BASE[kind]
        for index in sorted(i for i in eds.od.indices if base <= i < base + 0x200):
            out.append((ObjRef(index, 0x01), f"{kind.upper()}{index - base + 1}"))
    return out


def file_cob_ids(eds: EdsFile) -> list[FileCobId]:
    """Every COB-ID object the file gives a value (see the module docstring)."""
    out: list[FileCobId] = []
    for obj, what in _cob_objects(eds):
        name = eds.text.section_name(obj.index, None if obj == OBJ_EMCY_COB_ID else obj.sub)
        sec = eds.text.section(name)
        if sec is None:
            continue
        key = "ParameterValue" if sec.get("ParameterValue") not in (None, "") else "DefaultValue"
        raw = sec.get(key)
        if raw in (None, ""):
            continue
        try:
            value, relative = parse_int(raw)
        except ValueError:
            continue  # a warning of the loader already
        out.append(FileCobId(obj, what, value, relative, sec.name, sec.line_of(key)))
    return out


def dcf_node_id(eds: EdsFile) -> tuple[int, EdsProblem] | None:
    """``[DeviceComissioning] NodeID`` (CiA 306 4.7.2; either spelling of the section) and
    where it is, when the file gives one of 1..127."""
    sec = eds.text.section("DeviceComissioning") or eds.text.section("DeviceCommissioning")
    raw = sec.get("NodeID") if sec is not None else None
    if sec is None or not raw:
        return None
    try:
        node_id, _ = parse_int(raw)
    except ValueError:
        return None
    if not 1 <= node_id <= 127:
        return None
    return node_id, EdsProblem(str(eds.path), sec.line_of("NodeID"), sec.name, "")


def foreign_cob_ids(eds: EdsFile, node_id: int | None) -> list[tuple[FileCobId, str, int]]:
    """The file's valid absolute COB-IDs that are the pre-defined COB-ID of a node other than
    ``node_id`` (None: of any node), each with that function and node id."""
    out = []
    for c in file_cob_ids(eds):
        if c.relative or not c.valid:
            continue
        owner = predefined_owner(c.cob_id)
        if owner is not None and owner[1] != node_id:
            out.append((c, owner[0], owner[1]))
    return out


def foreign_cob_id_problems(eds: EdsFile, node_id: int | None) -> list[EdsProblem]:
    """``eds lint``'s warnings: each absolute COB-ID of another node (``node_id``: the node the
    file is for, a DCF's NodeID; None for an EDS)."""
    out = []
    for c, function, owner in foreign_cob_ids(eds, node_id):
        out.append(EdsProblem(str(eds.path), c.line, c.section, foreign_text(c, function, owner)))
    return out


def foreign_text(c: FileCobId, function: str, owner: int) -> str:
    """``TPDO1 COB-ID 0x181 is absolute: the pre-defined TPDO1 COB-ID of node 1 ...``"""
    relative = f" (relative: $NODEID+0x{c.cob_id - owner:X})" if c.what == function else ""
    return (
        f"{c.what} COB-ID 0x{c.cob_id:03X} is absolute: the pre-defined {function} COB-ID of "
        f"node {owner}; at any other node id it is still node {owner}'s{relative}"
    )
