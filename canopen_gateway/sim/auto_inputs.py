"""The inputs of a simulated device known only from its EDS: its numeric TPDO-mapped objects,
driven by the motion model so that a plant engineer sees values move.

``mapped_inputs`` picks the objects (numeric, 2000h and above, mapped in a TPDO of the EDS's
default mapping); ``auto_value`` turns the model's position into a value of an object's data
type (REAL: position / 100; BOOLEAN: toggles every 1000 counts; integers: wrapped to the type's
width).

Imports: canopen_gateway.canopen.cia301 (data types), canopen_gateway.canopen.objref, sim.objects, sim.pdo. Nothing of bus/,
modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from typing import Any

import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.cia301 import (
    BOOLEAN,
    NUMERIC_TYPES,
    REAL32,
    REAL64,
    SIGNED_TYPES,
    TYPE_BITS,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.objects import ObjectValues, PersistentStore

#: numeric data types the default motion drives (REAL64 too: the simulator writes it)
_MOTION_TYPES = NUMERIC_TYPES | {REAL64}


def mapped_inputs(values: ObjectValues, store: PersistentStore, node_id: int) -> list[ObjRef]:
    """Numeric objects of the EDS's TPDO mappings (defaults, ``$NODEID`` resolved)."""
    values.load_defaults(node_id, store, 1)
    out: list[ObjRef] = []
    for n in pdo.numbers(values, "tpdo"):
        for e in pdo.mapping(values, "tpdo", n):
            obj = ObjRef(e.index, e.sub)
            var = values.vars.get((e.index, e.sub)) if e.index >= 0x1000 else None
            if var is None or obj in out or e.index < 0x2000:
                continue
            if var.data_type in _MOTION_TYPES:
                out.append(obj)
    return out


def auto_value(values: ObjectValues, obj: ObjRef, model: float) -> Any:
    """The value of ``obj`` for the model position ``model`` (counts)."""
    var = values.vars[(obj.index, obj.sub)]
    if var.data_type in (REAL32, REAL64):
        return round(model / 100.0, 3)
    bits = TYPE_BITS[var.data_type]
    if var.data_type == BOOLEAN:
        return int(model) // 1000 % 2
    signed = var.data_type in SIGNED_TYPES
    v = int(model) % (1 << bits) if bits < 32 else int(model)
    if signed and v >= 1 << (bits - 1):
        v -= 1 << bits
    return v
