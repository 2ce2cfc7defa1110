"""The simulated device's process values: its motion model written into the position and
velocity objects the profile's ``sim:`` hints name (or, for a device known only from its EDS,
into its TPDO-mapped inputs, ``auto_inputs.py``), with the device's calibration.

``ProcessModel`` belongs to one ``SimNode`` and owns the model, the calibration offset (counts
added to the model by a preset or a referencing run) and the time of its last sample. The
position a device shows is "direction x model + calibration offset + application offset"
(SGH10 manual 3.2, AP05 manual 4.4). Sans-I/O: ``now`` is the node's clock.

Imports: canopen_gateway.canopen.objref, sim.auto_inputs, sim.hints, sim.motion, sim.objects. Nothing of bus/,
modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.auto_inputs import auto_value
from canopen_gateway.sim.hints import SimHints
from canopen_gateway.sim.motion import Motion
from canopen_gateway.sim.objects import ObjectValues


class ProcessModel:
    """Motion model -> position / velocity objects, the calibration offset and its objects."""

    def __init__(
        self, values: ObjectValues, hints: SimHints, motion: Motion, auto_inputs: list[ObjRef]
    ) -> None:
        self.values = values
        self.hints = hints
        self.motion = motion
        self.auto_inputs = auto_inputs
        self.position_obj = hints.position
        self.velocity_obj = hints.velocity
        self.velocity_scale = hints.velocity_scale
        self.offset = 0  # counts added to the model (calibration / preset)
        self.sampled_at: float | None = None

    def power_on(self, now: float, stored_offset: int | None) -> None:
        """The model starts at ``now``; the stored calibration applies again (its objects too)."""
        self.motion.start(now)
        self.set_offset(stored_offset or 0, write_objects=bool(stored_offset))

    def set_offset(self, counts: int, *, write_objects: bool = True) -> None:
        """The calibration offset; its objects (SGH10 manual 4.7.2.44: 6509h = encoder value -
        position value) follow."""
        self.offset = counts
        if write_objects:
            for obj in self.hints.offset_objects:
                if self.values.has(*obj):
                    self.values.set(*obj, -counts)

    def invalidate(self) -> None:
        """The next ``sample`` recomputes even at the same ``now``."""
        self.sampled_at = None

    def sample(self, now: float) -> bool:
        """Write the model's values at ``now``; False when they were already written at ``now``."""
        if self.sampled_at == now:
            return False
        self.sampled_at = now
        pos, vel = self.motion.sample(now)
        for i, obj in enumerate(self.auto_inputs):
            self.values.set(*obj, auto_value(self.values, obj, pos + 7 * i))
        if self.position_obj is not None:
            self.values.set(*self.position_obj, self.position_from_model(pos))
        if self.velocity_obj is not None:
            self.values.set(*self.velocity_obj, int(round(vel * self.velocity_scale)))
        return True

    def direction_sign(self) -> int:
        """-1 when the profile's direction bit is set (e.g. 6000h bit 0, AP05 manual 5.7.2.49)."""
        d = self.hints.direction
        if d is None or not self.values.has(*d[0]):
            return 1
        return -1 if int(self.values.get(*d[0], 0)) >> d[1] & 1 else 1

    def position_from_model(self, model_counts: float) -> int:
        app = self.hints.application_offset
        app_offset = int(self.values.get(*app, 0)) if app is not None else 0
        return self.direction_sign() * int(round(model_counts)) + self.offset + app_offset

    def calibrate(self, preset: int, now: float) -> None:
        """Make the position read ``preset`` (+ the application offset) now: "Position value =
        0 + calibration value + offset value" (SGH10 manual 3.2, AP05 manual 4.4)."""
        model, _ = self.motion.sample(now)
        self.set_offset(int(preset) - self.direction_sign() * int(round(model)))
        self.sampled_at = None
