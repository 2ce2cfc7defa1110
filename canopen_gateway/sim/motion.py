"""Motion models of a simulated sensor: where the measured axis is at a given time.

A model is a function of time returning (position in counts, velocity in counts/s): a triangle
ramp between two limits, a sine, a bounded random walk, or a fixed hold. Time counts from the
first sample (the device's first power-on), where the position is ``start``. The speed never
exceeds ``speed`` counts/s. Given the same configuration and the same times, a model returns the
same values (the random walk draws its way-points from ``seed``).

The model knows nothing of objects or scaling: the node writes its output into the position
and velocity objects named by the profile's ``sim:`` hints. Imports: the standard library only.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, fields
from typing import Any, Literal

MotionKind = Literal["ramp", "sine", "random_walk", "hold"]


@dataclass(frozen=True)
class MotionConfig:
    """Parameters of a motion model, in counts of the position object."""

    kind: MotionKind = "ramp"
    min: float = 0.0
    max: float = 10000.0
    speed: float = 1000.0  # counts/s: ramp speed, speed limit of sine and random walk
    period_s: float = 10.0  # sine period (stretched if the speed limit requires it)
    step_s: float = 0.5  # random walk: time between way-points
    seed: int = 0
    hold: float | None = None  # position of kind "hold" (default: middle of min..max)
    start: float | None = None  # position at the first sample (default: min; sine: middle)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> MotionConfig:
        """From a profile's ``sim: motion:`` mapping; unknown keys are an error."""
        if not d:
            return cls()
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown motion keys {sorted(unknown)}; known: {sorted(names)}")
        cfg = cls(**d)
        if cfg.kind not in ("ramp", "sine", "random_walk", "hold"):
            raise ValueError(f"motion kind {cfg.kind!r} is not ramp, sine, random_walk or hold")
        if cfg.max < cfg.min:
            raise ValueError(f"motion max {cfg.max} is below min {cfg.min}")
        return cfg


class Motion:
    """A motion model; ``sample(now)`` -> (position counts, velocity counts/s)."""

    def __init__(self, config: MotionConfig | None = None) -> None:
        self.config = config or MotionConfig()
        self._origin_s: float | None = None
        self._waypoints: list[float] = []
        self._rng = random.Random(self.config.seed)
        self.frozen_at: tuple[float, float] | None = None

    def start(self, now: float) -> None:
        """Time origin of the model (the first power-on); later calls change nothing."""
        if self._origin_s is None:
            self._origin_s = now

    def freeze(self, position: float | None) -> None:
        """Hold the axis still at ``position`` (None: release and follow the model again)."""
        self.frozen_at = None if position is None else (float(position), 0.0)

    def sample(self, now: float) -> tuple[float, float]:
        if self._origin_s is None:
            self._origin_s = now
        if self.frozen_at is not None:
            return self.frozen_at
        c = self.config
        t = max(0.0, now - self._origin_s)
        span = c.max - c.min
        if c.kind == "hold" or span <= 0 or c.speed <= 0:
            if c.hold is not None:
                return c.hold, 0.0
            return (c.start if c.start is not None else c.min + span / 2), 0.0
        start = c.start
        if c.kind == "ramp":
            # phase 0 at min; start inside [min, max] on the rising edge
            frac = 0.0 if start is None else min(max((start - c.min) / span, 0.0), 1.0)
            return self._ramp(t + frac * span / c.speed, c.min, span, c.speed)
        if c.kind == "sine":
            amp = span / 2
            omega = 2 * math.pi / max(c.period_s, 1e-6)
            omega = min(omega, c.speed / amp)
            x = 0.0 if start is None else min(max((start - c.min - amp) / amp, -1.0), 1.0)
            phase = math.asin(x)
            return (
                c.min + amp + amp * math.sin(omega * t + phase),
                amp * omega * math.cos(omega * t + phase),
            )
        return self._random_walk(t)

    @staticmethod
    def _ramp(t: float, lo: float, span: float, speed: float) -> tuple[float, float]:
        half_s = span / speed
        phase = t % (2 * half_s)
        if phase < half_s:
            return lo + speed * phase, speed
        return lo + span - speed * (phase - half_s), -speed

    def _random_walk(self, t: float) -> tuple[float, float]:
        c = self.config
        k = int(t // c.step_s)
        while len(self._waypoints) < k + 2:
            if not self._waypoints:
                first = c.start if c.start is not None else c.min + (c.max - c.min) / 2
                self._waypoints.append(min(c.max, max(c.min, first)))
                continue
            prev = self._waypoints[-1]
            step = self._rng.uniform(-1.0, 1.0) * c.speed * c.step_s
            self._waypoints.append(min(c.max, max(c.min, prev + step)))
        a, b = self._waypoints[k], self._waypoints[k + 1]
        frac = (t - k * c.step_s) / c.step_s
        return a + (b - a) * frac, (b - a) / c.step_s
