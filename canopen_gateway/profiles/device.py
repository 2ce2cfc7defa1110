"""What a device's file says about the device itself: how an EDS-only node is supervised
(``device_supervision``, ``stale_after_from_event_timers``), the identity 1018h it must hold
(``identity_check``: what is compared, and in words what cannot be) and whether the gateway verifies its PDO mapping
(``node_verifies_mapping``).

Imports: profiles.schema, canopen_gateway.eds.pdos (od_var), cia301 (the error-control objects), objref, canopen; profiles.loader and
profiles.node_setup for types only. Nothing of bus/, modbus/, zenoh_bridge/, config.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import canopen

from canopen_gateway.canopen.cia301 import (
    OBJ_GUARD_TIME,
    OBJ_HEARTBEAT_PRODUCER,
    OBJ_LIFE_TIME_FACTOR,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.pdos import od_var
from canopen_gateway.profiles.schema import Boot, Pdo

if TYPE_CHECKING:
    from canopen_gateway.profiles.loader import LoadedProfile
    from canopen_gateway.profiles.node_setup import NodeSetup


#: an EDS-only node without supervision: values are stale after this many event timer periods
STALE_EVENT_TIMER_MULTIPLE = 3


def stale_after_from_event_timers(tpdos: Sequence[Pdo]) -> int | None:
    """``stale_after_ms`` of a node the gateway cannot supervise: 3 x the longest event timer
    of its TPDOs (None when no TPDO has one)."""
    timers = [p.event_timer_ms for p in tpdos if p.event_timer_ms]
    return STALE_EVENT_TIMER_MULTIPLE * max(timers) if timers else None


def device_supervision(od: canopen.ObjectDictionary) -> Boot:
    """How an EDS-only node is supervised when its config does not say: heartbeat when the
    device has a writable 1017h (CiA 301 7.5.2.25), else node guarding when it has writable
    100Ch and 100Dh and no 1017h (guard time and life time factor from the file when not 0;
    else 100 ms and 3), else none."""
    def settable(obj: ObjRef) -> canopen.objectdictionary.ODVariable | None:
        var = od_var(od, obj)  # an integer the gateway can write (a damaged entry is not)
        ok = var is not None and var.data_type in (0x5, 0x6, 0x7) and var.access_type in ("rw", "wo", "rww", "rwr")
        return var if ok else None

    hb = settable(OBJ_HEARTBEAT_PRODUCER)
    if hb is not None:
        lo, hi = hb.min, hb.max  # a file whose limits exclude 100 ms: the nearest allowed time
        if isinstance(lo, int) and isinstance(hi, int) and 0 < hi and lo <= hi and not lo <= 100 <= hi:
            return Boot(heartbeat_ms=min(max(100, lo, 1), hi, 65535))
        return Boot()
    gt, ltf = settable(OBJ_GUARD_TIME), settable(OBJ_LIFE_TIME_FACTOR)
    if gt is not None and ltf is not None and od_var(od, OBJ_HEARTBEAT_PRODUCER) is None:
        gt_ms = gt.default if isinstance(gt.default, int) and 0 < gt.default <= 65535 else 100
        lt = ltf.default if isinstance(ltf.default, int) and 0 < ltf.default <= 255 else 3
        return Boot(supervision="guarding", guard_time_ms=gt_ms, life_time_factor=lt)
    return Boot(supervision="none")


#: CiA 306 placeholders: a VendorNumber / ProductNumber of 0 or all ones says nothing
_NOT_GIVEN = (0, 0xFFFFFFFF)


#: the identity objects the file's [DeviceInfo] gives, by 1018h sub-index (CiA 306 4.6.2)
_IDENTITY_KEYS = {1: ("VendorNumber", "vendor"), 2: ("ProductNumber", "product")}


@dataclass(frozen=True)
class IdentityCheck:
    """What the gateway compares in 1018h at every boot (``expected``: object, value) and, in
    words, each part of the identity it cannot compare (``not_checked``: ``check`` prints them
    as notes, the node logs them at start)."""

    expected: tuple[tuple[ObjRef, int], ...]
    not_checked: tuple[str, ...]


def identity_check(lp: LoadedProfile) -> IdentityCheck:
    """What the device at this node must hold in 1018h (CiA 301 7.5.2.20), as its EDS/DCF
    says: sub 01h = VendorNumber and sub 02h = ProductNumber of [DeviceInfo], each when the
    file gives it (a file with VendorNumber alone: a device of another vendor is refused), and
    for a DCF sub 04h = the ParameterValue of 1018h:04 (the serial number of the commissioned
    device). Only the sub-indices the file defines are compared (CiA 301 makes only 1018h:01
    mandatory: a file with 1018h:01 alone says its devices have no product code to read). A
    number the file contradicts itself on ([DeviceInfo] and the value of 1018h differ; ``eds
    lint`` warns) is not compared: the file does not say which device it describes, and a right
    device must not be refused. Each part not compared is said in ``not_checked``."""
    info = lp.od.device_information
    file = lp.eds_path.name
    out: list[tuple[ObjRef, int]] = []
    why_not: dict[ObjRef, str] = {}  # a part the file gives no comparable number for
    for sub, number in ((1, info.vendor_number), (2, info.product_number)):
        key = _IDENTITY_KEYS[sub][0]
        obj = ObjRef(0x1018, sub)
        var = od_var(lp.od, obj)
        held = None if var is None else getattr(var, "value", None)
        if var is not None and held is None:
            held = getattr(var, "default", None)
        if number is None:
            why_not[obj] = f"{file} gives no {key} in [DeviceInfo]"
        elif number in _NOT_GIVEN:
            why_not[obj] = f"{file} gives no {key} ({key}=0x{int(number):X} in [DeviceInfo] stands for none)"
        elif var is None:
            why_not[obj] = f"{file} does not define {obj}"
        elif isinstance(held, int) and held not in _NOT_GIVEN and held != int(number):
            why_not[obj] = f"{file} says {key} 0x{int(number):X} but 0x{held:X} for {obj}"
        else:
            out.append((obj, int(number)))
    serial = od_var(lp.od, ObjRef(0x1018, 4))
    held = getattr(serial, "value", None)
    if lp.eds_path.suffix.lower() == ".dcf" and isinstance(held, int) and held not in _NOT_GIVEN:
        out.append((ObjRef(0x1018, 4), held))
    if not out:
        absent = f"{file} gives no VendorNumber or ProductNumber in [DeviceInfo]"
        reasons = absent if all(" gives no " in w for w in why_not.values()) else "; ".join(why_not.values())
        return IdentityCheck((), (f"identity (1018h) not checked: {reasons}: any device at this node id is configured",))  # fmt: skip
    compared = ", ".join(f"{o} ({_IDENTITY_KEYS.get(o.sub, ('', 'serial number'))[1]})" for o, _ in out)
    gaps = tuple(
        f"{o} ({_IDENTITY_KEYS[o.sub][1]}) not checked: {why}; only {compared} is compared"
        for o, why in why_not.items()
    )
    return IdentityCheck(tuple(out), gaps)


def expected_identity(lp: LoadedProfile) -> tuple[tuple[ObjRef, int], ...]:
    """The 1018h objects and values a device at this node must hold (``identity_check``)."""
    return identity_check(lp).expected


def node_verifies_mapping(lp: LoadedProfile, node: NodeSetup) -> bool:
    """``verify_mapping``: the node's setting, else on for EDS-only nodes and for profiles
    that ask for it; never for a profile whose mapping objects do not describe the layout."""
    if lp.profile.verify_mapping is False:
        return False
    if node.verify_mapping is not None:
        return node.verify_mapping
    return node.eds_only or bool(lp.profile.verify_mapping)
