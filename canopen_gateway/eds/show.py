"""Text renderings of an EDS: ``canopen-gateway eds show`` and ``profile init``.

``render(eds, node_id)``: the objects (index, sub, name, type, access, PDO-mappable, default,
limits) and the PDOs (COB-ID, transmission, event timer, mapping) as Markdown tables.
``overlay_profile(eds, eds_ref)``: an editable overlay profile (YAML text) naming the signals
the gateway derives from the EDS, with the fields a user may add.

Imports: canopen (dictionary types), canopen_gateway.canopen.cia301, canopen_gateway.eds, canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from typing import Any

import yaml
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

from canopen_gateway.canopen.cia301 import COB_ID_INVALID
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds import EdsFile
from canopen_gateway.eds.parse import DATA_TYPES
from canopen_gateway.eds.pdos import (
    EdsPdo,
    access_of,
    eds_pdos,
    object_name,
    od_var,
    signal_type,
    slug,
    unique_names,
)


def _vars(eds: EdsFile) -> list[tuple[ObjRef, ODVariable]]:
    out = []
    for index in sorted(eds.od.indices):
        entry = eds.od[index]
        if isinstance(entry, ODVariable):
            out.append((ObjRef(index, 0), entry))
        elif isinstance(entry, (ODArray, ODRecord)):
            for sub in sorted(entry.subindices):
                out.append((ObjRef(index, sub), entry[sub]))
    return out


def _shown(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, int) and not isinstance(v, bool) and v > 9:
        return f"0x{v:X}"
    return str(v).replace("|", "\\|")


def _pdo_rows(pdos: list[EdsPdo]) -> list[str]:
    rows = []
    for p in pdos:
        state = "enabled" if p.enabled else "disabled (COB-ID bit 31)" if p.cob_id & COB_ID_INVALID else "no entries"
        mapping = ", ".join(f"{o}/{b}" for o, b in p.entries) or "-"
        rows.append(
            f"| {p.kind.upper()}{p.number} | 0x{p.cob_id & 0x7FF:03X} | {state} | "
            f"{'' if p.transmission_type is None else p.transmission_type} | "
            f"{'' if p.event_timer_ms is None else p.event_timer_ms} | {p.bits} | "
            f"{'rw' if p.mapping_writable else 'ro'} | {mapping} |"
        )
    return rows


def render(eds: EdsFile, node_id: int | None = None) -> str:
    lines = [f"# {eds.product_name} ({eds.path.name})", ""]
    lines += ["| object | name | type | access | PDO | default | limits |", "|---|---|---|---|---|---|---|"]
    for obj, var in _vars(eds):
        limits = ""
        if var.min is not None or var.max is not None:
            limits = f"{_shown(var.min)}..{_shown(var.max)}"
        raw = getattr(var, "default_raw", None)
        default = raw if isinstance(raw, str) and "$NODEID" in raw.upper() else var.default
        lines.append(
            f"| {obj} | {var.name.replace('|', ' ')} | {DATA_TYPES.get(var.data_type or 0, hex(var.data_type or 0))} | "
            f"{var.access_type} | {'yes' if var.pdo_mappable else ''} | {_shown(default)} | {limits} |"
        )
    lines += ["", f"PDOs{f' for node {node_id}' if node_id else ' ($NODEID = 0)'}:", ""]
    lines += ["| PDO | COB-ID | state | transmission | event timer ms | bits | mapping object | mapping |",
              "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    lines += _pdo_rows(eds_pdos(eds.od, node_id, "tpdo") + eds_pdos(eds.od, node_id, "rpdo"))
    return "\n".join(lines) + "\n"


def overlay_profile(eds: EdsFile, eds_ref: str) -> str:
    """An overlay profile for ``eds`` with the signals derived from its enabled PDOs."""
    od = eds.od
    t_objs: list[ObjRef] = []
    r_objs: list[ObjRef] = []
    for p in eds_pdos(od, None, "tpdo"):
        if p.enabled:
            t_objs += [o for o, _ in p.entries if o.index >= 0x1000 and o not in t_objs]
    for p in eds_pdos(od, None, "rpdo"):
        if p.enabled:
            r_objs += [o for o, _ in p.entries if o.index >= 0x1000 and o not in r_objs]
    objs = t_objs + [o for o in r_objs if o not in t_objs]
    names = unique_names(od, objs, set())
    head = (
        f"# Overlay profile for {eds.product_name} ({eds.path.name}), written by\n"
        "# `canopen-gateway profile init`. Types, access and the PDO layout come from the EDS;\n"
        "# rename signals and add what the EDS cannot say (docs/devices.md, 'Overlay profile'):\n"
        "#   unit, scale, offset, min, max, values {raw: text}, bits [{bit, name, description}],\n"
        "#   description; emcy {code: text}; boot {heartbeat_ms, sdo: [...]}; constraints;\n"
        "#   features; verify_mapping.\n"
    )
    top = yaml.safe_dump(
        {"family": slug(eds.path.stem) or "device", "title": eds.product_name, "eds": eds_ref},
        sort_keys=False,
        allow_unicode=True,
    )
    # no mapped object: an empty list, which the profile loader takes (a bare key is null)
    text = top + ("signals:\n" if objs else "signals: []  # no PDO-mapped object in the file\n")
    for o in objs:
        var = od_var(od, o)
        kind = "RPDO, written by the gateway" if o in r_objs else "TPDO, read"
        # the description an EDS-only node's register map shows: the object's name and index
        described = yaml.safe_dump(f"{object_name(od, o)} ({o})", allow_unicode=True, width=1000)
        text += (
            f"  - name: {names[o]}\n"
            f'    object: "{o}"  # {signal_type(var)}, {access_of(var)}, {kind}\n'
            f"    description: {described.splitlines()[0]}\n"
        )
    return head + text
