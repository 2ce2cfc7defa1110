"""The simulated device's objects as its SDO server reads and writes them: what a read or a
write checks and what a write sets off.

Module-level functions taking the node as ``ObjectHost`` (a Protocol: what they use of a
``SimNode``; SGH10 manual 000/003 section numbers):

- ``sdo_read`` / ``sdo_write``, the SDO server's callbacks (4.4.1): objects the device does not
  use (sim hint ``unused_objects``) aborted with the hint's code; the access and size checks of
  ``ObjectValues.check_write``; the features' ``before_sdo_read`` / ``before_sdo_write``
  (which may abort) and ``after_sdo_write``; a 1003h entry beyond the count aborted 0x08000024;
- ``check_profile_range``: a value outside the profile's min..max (engineering values) is
  aborted 0x06090030;
- ``write_object``, the DS-301 objects with rules or side effects, then the value stored:
  1003h:00 accepts only 0 and clears the error history (4.7.2.4); 1010h "save" / 1011h "load"
  (4.7.2.11/12) on sub-indices 1 (all), 2 (1000h-1FFFh), 3 (6000h-9FFFh), 4 (2000h-5FFFh), a
  wrong signature aborted 0x08000020, the calibration kept with the application parameters;
  1005h (SYNC generator, bit 30) and 1014h (EMCY valid, bit 31 clear) change their COB-ID only
  while inactive (0x08000022); a PDO's COB-ID and mapping follow the PDO parameter rules of
  ``sim.pdo.check_write`` (4.1, 4.2.1.1) and, with the sim hint ``cob_id_change_preop_only``,
  are writable in PRE-OPERATIONAL only; 1017h reschedules the heartbeat; the profile's preset
  or calibration trigger calibrates the position (SGH10 manual 3.2, AP05 manual 4.4).

Imports: canopen_gateway.canopen.cia301 (COB-ID bits), canopen_gateway.canopen.objref, canopen_gateway.canopen.states, sim.objects (abort
codes), sim.pdo; canopen_gateway.profiles and the other sim parts for types only. Nothing of bus/, modbus/,
zenoh_bridge/.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.cia301 import COB_ID_INVALID, COB_ID_MASK_29BIT, SYNC_GENERATOR
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.sim.objects import (
    ABORT_NO_DATA,
    ABORT_RANGE,
    ABORT_STATE,
    ABORT_STORE,
    ObjectValues,
    PersistentStore,
    SdoAbortError,
)

if TYPE_CHECKING:
    from canopen_gateway.profiles import LoadedProfile
    from canopen_gateway.sim.emcy import EmcyProducer
    from canopen_gateway.sim.error_control import ErrorControl
    from canopen_gateway.sim.features import SimFeature
    from canopen_gateway.sim.hints import SimHints

# 1010h / 1011h signatures, ASCII "save" / "load" little-endian (SGH10 manual 4.7.2.11/12)
SIGNATURE_SAVE = 0x65766173
SIGNATURE_LOAD = 0x64616F6C


class ObjectHost(Protocol):
    """What an SDO read or write uses of its node."""

    values: ObjectValues
    store: PersistentStore
    hints: SimHints
    profile: LoadedProfile
    features: list[SimFeature]
    emcy: EmcyProducer
    error_control: ErrorControl
    now: float
    node_id: int
    nmt_state: NmtState

    @property
    def position_offset(self) -> int: ...

    def set(self, index: int, sub: int, value: Any) -> None: ...
    def calibrate(self, preset: int, now: float) -> None: ...
    def update_process(self, now: float) -> None: ...
    def invalidate_process(self) -> None: ...


def check_profile_range(profile: LoadedProfile, obj: ObjRef, value: Any) -> None:
    """Abort 0x06090030 when ``value`` is outside the profile's min..max for ``obj``."""
    sig = profile.profile.signal_for(obj)
    if sig is None or not isinstance(value, (int, float)):
        return
    if isinstance(value, int) and sig.type in ("int8", "int16", "int24", "int32", "int64"):
        bits = sig.bit_length  # an EDS UNSIGNED object the profile reads as signed
        if value >= 1 << (bits - 1):
            value -= 1 << bits
    eng = value * sig.scale + sig.offset  # profile min/max are engineering values
    tol = 1e-9 * max(1.0, abs(eng))
    if (sig.min is not None and eng < sig.min - tol) or (
        sig.max is not None and eng > sig.max + tol
    ):
        raise SdoAbortError(ABORT_RANGE, f"{obj} value {eng} outside {sig.min}..{sig.max}")


def _check_preop(node: ObjectHost, obj: ObjRef) -> None:
    if node.hints.cob_id_change_preop_only and node.nmt_state != NmtState.PRE_OPERATIONAL:
        raise SdoAbortError(ABORT_STATE, f"{obj} is writable in PRE-OPERATIONAL only")


def _store_command(node: ObjectHost, obj: ObjRef, value: Any) -> None:
    """1010h save / 1011h load (SGH10 manual 4.7.2.11/12)."""
    index, sub = obj
    if index == 0x1010:
        if value != SIGNATURE_SAVE:
            raise SdoAbortError(ABORT_STORE, "1010h expects the signature 'save'")
        node.values.save(node.node_id, node.store, sub)
        if sub in (1, 3, 4):  # the calibration belongs to the application parameters
            node.store.position_offset = node.position_offset
        return
    if value != SIGNATURE_LOAD:
        raise SdoAbortError(ABORT_STORE, "1011h expects the signature 'load'")
    node.values.restore(node.store, sub)
    if sub in (1, 3, 4):
        node.store.position_offset = None


def _calibration_write(node: ObjectHost, obj: ObjRef, value: Any, now: float) -> None:
    h = node.hints
    if h.calibration_trigger is None and obj == h.preset:
        node.calibrate(int(value), now)
    elif obj == h.calibration_trigger and int(value) == h.calibration_trigger_value:
        preset = int(node.values.get(*h.preset, 0)) if h.preset is not None else 0
        node.calibrate(preset, now)
        if h.calibration_done_value is not None:
            node.values.set(*obj, h.calibration_done_value)


def write_object(node: ObjectHost, obj: ObjRef, value: Any, now: float) -> None:
    """DS-301 objects with rules or side effects, then store the value."""
    index, sub = obj
    if index == 0x1003 and sub == 0:
        if value != 0:  # SGH10 manual 4.7.2.4: only 0 is written, clearing the list
            raise SdoAbortError(ABORT_RANGE, "1003h:00 accepts only 0")
        node.emcy.clear_history()
        return
    if index in (0x1010, 0x1011) and sub >= 1:
        _store_command(node, obj, value)
        return
    if index in (0x1005, 0x1014):
        _check_preop(node, obj)
        old = int(node.values.get(index, 0, 0))
        # 1005h: bit 30 set = this node generates SYNC; 1014h: bit 31 set = EMCY invalid
        guard_bit = SYNC_GENERATOR if index == 0x1005 else COB_ID_INVALID
        active = bool(old & guard_bit) if index == 0x1005 else not old & guard_bit
        if active and (old ^ int(value)) & COB_ID_MASK_29BIT:
            raise SdoAbortError(ABORT_STATE, f"{obj}: invalidate before changing the COB-ID")
    which = pdo.pdo_of(index)
    if which is not None:
        _, _, is_map = which
        if is_map or sub == 1:  # COB-ID and mapping (SGH10 manual 4.1, 4.2.1.1)
            _check_preop(node, obj)
        pdo.check_write(node.values, index, sub, value, require_mappable=node.hints.require_mappable)
    node.set(index, sub, value)
    if index == 0x1017:
        node.error_control.schedule_heartbeat(now)
    h = node.hints
    if obj in (h.preset, h.calibration_trigger):
        _calibration_write(node, obj, value, now)
    if obj == h.application_offset or (h.direction is not None and obj == h.direction[0]):
        node.invalidate_process()


def sdo_read(node: ObjectHost, index: int, sub: int) -> bytes:
    """The SDO server's read of ``index:sub`` (raises SdoAbortError)."""
    now = node.now
    var = node.values.var(index, sub)  # 0x06020000 / 0x06090011 first
    obj = ObjRef(index, sub)
    if obj in node.hints.unused_objects:
        raise SdoAbortError(node.hints.unused_abort, f"{obj} is not used by this device")
    node.update_process(now)
    for b in node.features:
        code = b.before_sdo_read(obj, now)
        if code is not None:
            raise SdoAbortError(code)
    if index == 0x1003 and sub > 0 and var.readable:
        if sub > int(node.values.get(0x1003, 0, 0)):
            raise SdoAbortError(ABORT_NO_DATA, f"1003h holds fewer than {sub} errors")
    return node.values.read_bytes(index, sub)


def sdo_write(node: ObjectHost, index: int, sub: int, data: bytes, size_given: bool) -> None:
    """The SDO server's write of ``data`` to ``index:sub`` (raises SdoAbortError)."""
    now = node.now
    obj = ObjRef(index, sub)
    if obj in node.hints.unused_objects:
        node.values.var(index, sub)
        raise SdoAbortError(node.hints.unused_abort, f"{obj} is not used by this device")
    _, value = node.values.check_write(index, sub, data, size_given)
    check_profile_range(node.profile, obj, value)
    for b in node.features:
        code = b.before_sdo_write(obj, value, now)
        if code is not None:
            raise SdoAbortError(code)
    write_object(node, obj, value, now)
    for b in node.features:
        b.after_sdo_write(obj, value, now)
