"""The register map as the tag imports of PLC and SCADA tools read it (``canopen-gateway
registers --format modicon|kepware``). Pure: a ``RegisterMap`` in, CSV text out.

Modicon addresses: the 6-digit, 1-based convention of Modbus tools (Modicon 984 reference):
coils 000001+, discrete inputs 100001+, input registers 300001+, holding registers 400001+;
protocol address 0 is ...001. A value of several registers starts at its first register.

* ``modicon``: ``unit_id,modicon,words,iec_type,word_order,node,signal,unit,description``, one
  row per value or bit; ``iec_type`` the IEC 61131-3 elementary type (BOOL, INT, UINT, DINT,
  UDINT, LINT, ULINT, REAL, LREAL, STRING); ``word_order`` (big: high word first) for values of
  several registers. The columns are fixed (no ``network`` column, unlike ``--format csv``): a
  node's name is unique in the gateway, and a gateway register of one CAN network names it in
  its description.
* ``kepware``: a KEPServerEX tag import (CSV) for its Modbus TCP/IP Ethernet driver, one device
  (unit id) per file: the columns of KEPServerEX's own tag export; ``Address`` the Modicon
  address (a string ``4xxxxx.nH``: n bytes, high byte first, the driver's string syntax);
  ``Data Type`` the driver's names (Boolean, Short, Word, Long, DWord, LLong, QWord, Float,
  Double, String); ``Client Access`` RO or R/W; ``Scan Rate`` in ms (process data and
  diagnostics 100, configuration objects read by SDO 1000). Tag names are unique in the file,
  made of the node and signal names (a gateway register of one CAN network: ``gateway_``, the
  network's name, the register's; KEPServerEX allows letters, digits and ``_``); a name two
  points share (a node's ``alive`` is an input register and a discrete input) carries the
  table (``_IR``, ``_DI``, ``_HR``, ``_CO``). The driver's word order is one setting per device
  (``First word low``): a point whose order differs from the map's says so in its description.

Imports: northbound.regmap (RegisterMap, Point).
"""

from __future__ import annotations

import csv
import io
import re
from collections import Counter

from canopen_gateway.northbound.regmap import Point, RegisterMap

MODICON_HEADER = ["unit_id", "modicon", "words", "iec_type", "word_order", "node", "signal", "unit", "description"]  # fmt: skip
#: the columns of a KEPServerEX tag export (Modbus TCP/IP Ethernet driver), in its order
KEPWARE_HEADER = [
    "Tag Name", "Address", "Data Type", "Respect Data Type", "Client Access", "Scan Rate",
    "Scaling", "Raw Low", "Raw High", "Scaled Low", "Scaled High", "Scaled Data Type",
    "Clamp Low", "Clamp High", "Eng Units", "Description", "Negate Value",
]  # fmt: skip

#: Modicon reference: the leading digit of each table (coils 0xxxxx ... holding 4xxxxx)
TABLE_DIGIT = {"co": 0, "di": 1, "ir": 3, "hr": 4}
TABLE_SUFFIX = {"co": "CO", "di": "DI", "ir": "IR", "hr": "HR"}

#: register type -> IEC 61131-3 elementary type
IEC_TYPE = {
    "bool": "BOOL", "int16": "INT", "uint16": "UINT", "int32": "DINT", "uint32": "UDINT",
    "int64": "LINT", "uint64": "ULINT", "float32": "REAL", "float64": "LREAL", "string": "STRING",
    "time_of_day": "ULINT", "time_difference": "ULINT",
}  # fmt: skip
#: register type -> KEPServerEX data type (Modbus TCP/IP Ethernet driver)
KEPWARE_TYPE = {
    "bool": "Boolean", "int16": "Short", "uint16": "Word", "int32": "Long", "uint32": "DWord",
    "int64": "LLong", "uint64": "QWord", "float32": "Float", "float64": "Double",
    "string": "String", "time_of_day": "QWord", "time_difference": "QWord",
}  # fmt: skip
#: KEPServerEX scan rates (ms): configuration objects come from the device by SDO on request
SCAN_RATE_MS = {"pdo": 100, "diag": 100, "sdo": 1000}


def modicon_address(p: Point) -> str:
    """``400101``: the 6-digit, 1-based Modicon address of the point's first register or bit."""
    return f"{TABLE_DIGIT[p.table]}{p.address + 1:05d}"


def _signal(p: Point) -> str:
    return f"{p.name}.bit{p.bit}" if p.kind == "bit" else p.name


def _word_order(p: Point) -> str:
    return p.word_order if p.count > 1 else ""


def to_modicon(rm: RegisterMap, unit: int | None = None) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(MODICON_HEADER)
    for p in _points(rm, unit):
        w.writerow([
            p.unit, modicon_address(p), p.count if p.table in ("hr", "ir") else 1,
            IEC_TYPE[p.type], _word_order(p), p.node or "(gateway)", _signal(p), p.unit_text,
            _description(p),
        ])  # fmt: skip
    return buf.getvalue()


def to_kepware(rm: RegisterMap, unit: int) -> str:
    points = _points(rm, unit)
    names = tag_names(points)
    device_order = kepware_word_order(rm, unit)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(KEPWARE_HEADER)
    for p, name in zip(points, names, strict=True):
        address = modicon_address(p)
        if p.type == "string":
            address += f".{p.count * 2}H"
        description = _description(p)
        if p.count > 1 and p.type != "string" and p.word_order != device_order:
            description = f"word order {p.word_order} (not the device's {device_order}). {description}"
        w.writerow([
            name, address, KEPWARE_TYPE[p.type], 1, "R/W" if p.access == "rw" else "RO",
            SCAN_RATE_MS[p.transport], "", "", "", "", "", "", "", "", p.unit_text,
            description, "",
        ])  # fmt: skip
    return buf.getvalue()


def kepware_word_order(rm: RegisterMap, unit: int) -> str:
    """The word order most values of several registers of ``unit`` have (the device setting)."""
    orders = Counter(p.word_order for p in _points(rm, unit) if p.count > 1 and p.type != "string")
    return orders.most_common(1)[0][0] if orders else "big"


def tag_names(points: list[Point]) -> list[str]:
    """Unique tag names: ``<node>_<signal>`` (``gateway_<name>`` for the gateway's registers,
    ``gateway_<network>_<name>`` for those of one CAN network, ``_bit<n>`` for a bit), the
    table added where two points would share one."""
    base = [_tag(p) for p in points]
    shared = {n for n, c in Counter(base).items() if c > 1}
    names = [f"{n}_{TABLE_SUFFIX[p.table]}" if n in shared else n for n, p in zip(base, points, strict=True)]
    seen: Counter[str] = Counter()
    out = []
    for n in names:  # the same table twice (cannot happen in a map; kept unique regardless)
        seen[n] += 1
        out.append(n if seen[n] == 1 else f"{n}_{seen[n]}")
    return out


def _tag(p: Point) -> str:
    owner = p.node or ("gateway" if p.network is None else f"gateway_{p.network}")  # a network's register
    text = f"{owner}_{p.name}" + (f"_bit{p.bit}" if p.kind == "bit" else "")
    return re.sub(r"[^A-Za-z0-9_]", "_", text)


def _points(rm: RegisterMap, unit: int | None) -> list[Point]:
    return [p for p in rm.sorted_points() if unit is None or p.unit == unit]


def _description(p: Point) -> str:
    text = " ".join(p.description.split())
    return f"{text} ({p.scaling})" if p.scaling else text
