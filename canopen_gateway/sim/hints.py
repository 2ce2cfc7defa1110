"""The simulator hints of a profile (``sim:`` in the profile YAML), read into one typed object.

Profiles describe their device for the simulator in a free-form ``sim:`` mapping; the node
options of a simulation (``SimNode(options=...)``) override it key by key. This module knows
which keys mean what (with the spellings the profiles use) and turns them into
:class:`SimHints`; unknown keys are kept in ``extra`` for features to read.

Keys read (all optional):
  position_object / position        object the motion model drives, e.g. "0x6004:00"
  velocity_object / velocity        object that gets the model's velocity
  velocity_scale / velocity_per_count_per_s
                                    velocity object value per count/s; else derived from
                                    velocity_unit "mm/s" + counts_per_mm, or velocity_window_ms
                                    (counts per window)
  motion                            MotionConfig keys (kind, min, max, speed, period_s, ...)
  typical_range_counts / position_range_counts / position_range    motion min, max
  typical_speed_counts_per_s / typical_speed_mm_s (x counts_per_mm) /
  typical_speed_rpm (x physical_counts_per_revolution / 60)          motion speed
  initial_position                  position at the first sample
  event_timer_mirror, operating_parameters_mirror, serial_number_mirror: [obj, obj, ...]
  position_mirrors: [obj, ...] (copies of the position object); old_object_mirrors: {a: b}
  mirrors: {a: b}                   further pairs of objects holding one value
  segmented_1008_segment_command / sdo_segment_upload_command
                                    fixed command byte of the last upload segment
  unused_objects + unused_objects_abort   objects whose access is refused with that code
  cob_id_change_preop_only          COB-ID / mapping writes only in PRE-OPERATIONAL
  guarding_with_heartbeat           answer guarding RTRs even while 1017h is non-zero
  tpdo_rtr                          TPDOs answer RTR (default True; bit 30 still applies)
  faults: {name: {emcy: code, register: bits}}     generic fault -> EMCY mapping
  emcy_on_position_error            EMCY code of the fault "sensor_error" (register bit 7)
  sdo_expedited_only                refuse segmented transfers (abort 0x05040001)
  tpdo_on_operational               send event-driven TPDOs without timer once on entering
                                    OPERATIONAL (default: only for profiles without sim hints)
  tpdo_on_change                    send event-driven TPDOs without timer when their data
                                    change (default: only for profiles without sim hints)
  input_cycle_ms                    how often such a device samples its inputs (default 10)
  sdo_timeout_s                     an unfinished SDO transfer is aborted after it (default 1)
  require_mappable                  a PDO mapping write refuses objects not marked PDOMapping
Calibration (position = direction x model + offset + application offset):
  calibration_object                writing P makes the position P (SGH10 6010h:01)
  calibration: {preset, trigger, trigger_value, done_value, application_offset}
                                    writing trigger_value to trigger makes the position the
                                    preset (+ application offset); trigger then reads done_value
  scaling: {preset, offset, operating_parameters, direction_bit}
  offset_objects: [obj, ...]        show model - position after a calibration (6509h)
  direction: {object, bit}          bit set = counting direction inverted

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.motion import MotionConfig


def _obj(v: Any) -> ObjRef | None:
    return None if v in (None, "") else ObjRef.parse(v)


def _first(d: dict[str, Any], *keys: str) -> Any:
    for k in keys:
        if d.get(k) is not None:
            return d[k]
    return None


@dataclass
class SimHints:
    position: ObjRef | None = None
    velocity: ObjRef | None = None
    velocity_scale: float = 1.0
    motion: MotionConfig = field(default_factory=MotionConfig)
    mirror_groups: list[tuple[ObjRef, ...]] = field(default_factory=list)
    segment_upload_command: int | None = None
    unused_objects: set[ObjRef] = field(default_factory=set)
    unused_abort: int = 0x08000024
    cob_id_change_preop_only: bool = False
    guarding_with_heartbeat: bool = False
    tpdo_rtr: bool = True
    faults: dict[str, dict[str, int]] = field(default_factory=dict)
    sdo_expedited_only: bool = False
    sdo_timeout_s: float = 1.0
    require_mappable: bool = False
    tpdo_on_operational: bool = False
    tpdo_on_change: bool = False
    input_cycle_s: float = 0.01
    preset: ObjRef | None = None
    calibration_trigger: ObjRef | None = None
    calibration_trigger_value: int = 1
    calibration_done_value: int | None = None
    application_offset: ObjRef | None = None
    offset_objects: list[ObjRef] = field(default_factory=list)
    direction: tuple[ObjRef, int] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, eds_only: bool = False) -> SimHints:
        """The hints of ``d``; ``eds_only``: a device known only from its EDS (a profile
        without ``sim:``), whose event-driven TPDOs default to ``tpdo_on_operational`` and
        ``tpdo_on_change`` (as most such devices do; the manual devices keep what their
        manuals describe)."""
        h = cls(extra=dict(d))
        h.position = _obj(_first(d, "position", "position_object"))
        h.velocity = _obj(_first(d, "velocity", "velocity_object"))
        scale = _first(d, "velocity_scale", "velocity_per_count_per_s")
        if scale is None and d.get("velocity_unit") == "mm/s" and d.get("counts_per_mm"):
            scale = 1.0 / float(d["counts_per_mm"])
        if scale is None and d.get("velocity_window_ms"):
            scale = float(d["velocity_window_ms"]) / 1000.0
        h.velocity_scale = 1.0 if scale is None else float(scale)
        h.motion = _motion(d)

        # DS-406 6200h = 1800h:05 is what feature ds406_cycle_timer simulates (on a CiA 401
        # device 6200h is a digital output)
        groups: list[tuple[ObjRef, ...]] = []
        for key in ("event_timer_mirror", "operating_parameters_mirror", "serial_number_mirror"):
            if d.get(key):
                groups.append(tuple(ObjRef.parse(x) for x in d[key]))
        if d.get("position_mirrors") and h.position is not None:
            groups.append((h.position, *(ObjRef.parse(x) for x in d["position_mirrors"])))
        for key in ("old_object_mirrors", "mirrors"):
            for a, b in (d.get(key) or {}).items():
                groups.append((ObjRef.parse(a), ObjRef.parse(b)))
        h.mirror_groups = _merge(groups)

        seg = _first(d, "sdo_segment_upload_command", "segmented_1008_segment_command")
        h.segment_upload_command = None if seg is None else int(seg)
        h.unused_objects = {ObjRef.parse(x) for x in d.get("unused_objects") or ()}
        if d.get("unused_objects_abort") is not None:
            h.unused_abort = int(d["unused_objects_abort"])
        h.cob_id_change_preop_only = bool(d.get("cob_id_change_preop_only", False))
        h.guarding_with_heartbeat = bool(d.get("guarding_with_heartbeat", False))
        h.tpdo_rtr = bool(d.get("tpdo_rtr", True))
        h.faults = {k: dict(v) for k, v in (d.get("faults") or {}).items()}
        if d.get("emcy_on_position_error") is not None and "sensor_error" not in h.faults:
            # DS-301 1001h bit 7 manufacturer-specific (SGH10 manual 4.7.2.2: sensor error)
            h.faults["sensor_error"] = {"emcy": int(d["emcy_on_position_error"]), "register": 0x80}
        h.sdo_expedited_only = bool(d.get("sdo_expedited_only", False))
        h.sdo_timeout_s = float(d.get("sdo_timeout_s", 1.0))
        h.require_mappable = bool(d.get("require_mappable", False))
        h.tpdo_on_operational = bool(d.get("tpdo_on_operational", eds_only))
        h.tpdo_on_change = bool(d.get("tpdo_on_change", eds_only))
        cycle_ms = d.get("input_cycle_ms", 10)
        if isinstance(cycle_ms, bool) or not isinstance(cycle_ms, (int, float)) or cycle_ms <= 0:
            raise ValueError(f"input_cycle_ms: {cycle_ms!r} is not a number of ms above 0")
        h.input_cycle_s = cycle_ms / 1000
        _calibration(h, d)
        return h


def _calibration(h: SimHints, d: dict[str, Any]) -> None:
    cal = dict(d.get("calibration") or {})
    scaling = dict(d.get("scaling") or {})
    h.preset = _obj(_first(d, "calibration_object") or cal.get("preset") or scaling.get("preset"))
    h.calibration_trigger = _obj(cal.get("trigger"))
    if cal.get("trigger_value") is not None:
        h.calibration_trigger_value = int(cal["trigger_value"])
    if cal.get("done_value") is not None:
        h.calibration_done_value = int(cal["done_value"])
    h.application_offset = _obj(cal.get("application_offset") or d.get("application_offset"))
    offsets = list(d.get("offset_objects") or [])
    if scaling.get("offset"):
        offsets.append(scaling["offset"])
    h.offset_objects = [ObjRef.parse(x) for x in offsets]
    direction = d.get("direction")
    if isinstance(direction, dict) and direction.get("object") is not None:
        h.direction = (ObjRef.parse(direction["object"]), int(direction.get("bit", 0)))
    elif scaling.get("operating_parameters") and scaling.get("direction_bit") is not None:
        h.direction = (ObjRef.parse(scaling["operating_parameters"]), int(scaling["direction_bit"]))


def _merge(groups: list[tuple[ObjRef, ...]]) -> list[tuple[ObjRef, ...]]:
    """Join groups sharing an object (6200h = 1800h:05 = 2200h...)."""
    merged: list[list[ObjRef]] = []
    for g in groups:
        hit = [m for m in merged if set(m) & set(g)]
        new = [o for m in hit for o in m]
        for m in hit:
            merged.remove(m)
        for o in g:
            if o not in new:
                new.append(o)
        merged.append(new)
    return [tuple(m) for m in merged if len(m) > 1]


def _motion(d: dict[str, Any]) -> MotionConfig:
    explicit = dict(d.get("motion") or {})
    rng = _first(d, "typical_range_counts", "position_range_counts", "position_range")
    if rng is not None:
        explicit.setdefault("min", float(rng[0]))
        explicit.setdefault("max", float(rng[1]))
    speed = d.get("typical_speed_counts_per_s")
    if speed is None and d.get("typical_speed_mm_s") and d.get("counts_per_mm"):
        speed = float(d["typical_speed_mm_s"]) * float(d["counts_per_mm"])
    if speed is None and d.get("typical_speed_rpm") and d.get("physical_counts_per_revolution"):
        speed = float(d["typical_speed_rpm"]) * float(d["physical_counts_per_revolution"]) / 60
    if speed is not None:
        explicit.setdefault("speed", float(speed))
    if d.get("initial_position") is not None:
        explicit.setdefault("start", float(d["initial_position"]))
    return MotionConfig.from_dict(explicit)
