"""Which TPDOs the gateway reads right after NMT start, and how.

A TPDO with transmission type 254/255 and no event timer is sent only when a mapped value
changes (DS-301 7.2.2.2; SGH10 manual 4.3.2 1800h:02, 1800h:05): after a boot-up or a loss the
gateway would wait forever for values it may serve as good. So right after NMT start it asks:
by RTR when the PDO allows remote requests (COB-ID bit 30 = 0), else by one SDO upload per
mapped object. Types 252/253 (on RTR only) are asked by RTR. Cyclic and SYNC PDOs need nothing.

Imports: pdo.codec, canopen.cia301, canopen.objref. No I/O.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from canopen_gateway.canopen.cia301 import COB_ID_NO_RTR, TRANSMISSION_EVENT, TRANSMISSION_RTR_ONLY
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.pdo.codec import TpdoCodec, pdo_objects


@dataclass(frozen=True)
class Refresh:
    """How a change-only TPDO is read after NMT start: ``rtr`` or one SDO upload per object."""

    codec: TpdoCodec
    how: str  # "rtr" | "sdo"
    objects: tuple[tuple[str, ObjRef, str], ...] = ()  # (signal, object, type) for "sdo"

CHANGE_ONLY = TRANSMISSION_EVENT
RTR_ONLY = TRANSMISSION_RTR_ONLY


def _od_default(lp: Any, obj: ObjRef, node_id: int) -> int | None:
    var = lp.od_var(obj)
    if var is None:
        return None
    raw = getattr(var, "default_raw", None)
    if isinstance(raw, str) and "$NODEID" in raw.upper():  # e.g. "$NODEID+0x180"
        try:
            return sum(
                node_id if t.strip().upper() == "$NODEID" else int(t.strip(), 0)
                for t in raw.split("+")
            )
        except ValueError:
            return None
    try:
        return int(var.default) if var.default is not None else None
    except (TypeError, ValueError):
        return None


def refresh_plan(
    lp: Any,
    node_id: int,
    variant: int | None,
    tpdos: Sequence[TpdoCodec],
    writes: Iterable[tuple[ObjRef, Any]],
) -> list[Refresh]:
    """The refresh of each change-only TPDO of a node (see the module docstring)."""
    w = list(writes)
    layout = {p.number: p for p in lp.profile.layout(variant)[0]}
    out: list[Refresh] = []
    for codec in tpdos:
        comm, _mapping = pdo_objects(lp, "tpdo", codec.number)
        base = layout.get(codec.number)
        tt = (
            base.transmission_type
            if base is not None
            else _od_default(lp, ObjRef(comm, 2), node_id)
        )
        et = base.event_timer_ms if base is not None else None
        if et is None:
            et = _od_default(lp, ObjRef(comm, 5), node_id)
        cob = _od_default(lp, ObjRef(comm, 1), node_id) or 0
        for obj, value in w:
            if obj.index != comm:
                continue
            if obj.sub == 2:
                tt = int(value)
            elif obj.sub == 5:
                et = int(value)
            elif obj.sub == 1:
                cob = int(value)
        if tt in RTR_ONLY or (tt in CHANGE_ONLY and not et):
            if not cob & COB_ID_NO_RTR:
                out.append(Refresh(codec, "rtr"))
                continue
            objects = []
            for f in codec.fields:
                if f.signal is None:
                    continue
                sig = lp.profile.signal(f.signal)
                objects.append((f.signal, f.obj, sig.type))
            out.append(Refresh(codec, "sdo", tuple(objects)))
    return out
