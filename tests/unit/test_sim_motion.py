"""Motion models of the simulator: deterministic given the times, speed-limited, bounded."""

from __future__ import annotations

import pytest

from canopen_gateway.sim.hints import SimHints
from canopen_gateway.sim.motion import Motion, MotionConfig


def samples(cfg: MotionConfig, times: list[float]) -> list[tuple[float, float]]:
    m = Motion(cfg)
    return [m.sample(t) for t in times]


TIMES = [i * 0.05 for i in range(400)]


@pytest.mark.parametrize("kind", ["ramp", "sine", "random_walk", "hold"])
def test_same_config_and_times_give_the_same_positions(kind: str) -> None:
    cfg = MotionConfig(kind=kind, min=0, max=1000, speed=300, seed=7)  # type: ignore[arg-type]
    assert samples(cfg, TIMES) == samples(cfg, TIMES)


@pytest.mark.parametrize("kind", ["ramp", "sine", "random_walk"])
def test_positions_stay_within_limits_and_speed_within_the_limit(kind: str) -> None:
    cfg = MotionConfig(kind=kind, min=-500, max=1500, speed=400, period_s=1.0)  # type: ignore[arg-type]
    out = samples(cfg, TIMES)
    assert all(-500 - 1e-6 <= p <= 1500 + 1e-6 for p, _ in out)
    assert all(abs(v) <= 400 + 1e-6 for _, v in out)
    for (p0, _), (p1, _) in zip(out, out[1:], strict=False):
        assert abs(p1 - p0) <= 400 * 0.05 + 1e-6


def test_ramp_goes_up_at_speed_then_back_down() -> None:
    m = Motion(MotionConfig(kind="ramp", min=0, max=100, speed=50))
    assert m.sample(0.0) == (0.0, 50)
    assert m.sample(1.0) == (50.0, 50)
    assert m.sample(3.0) == (50.0, -50)


def test_model_time_starts_at_the_first_sample_with_the_start_position() -> None:
    m = Motion(MotionConfig(kind="ramp", min=0, max=100, speed=10, start=40))
    assert m.sample(1000.0)[0] == pytest.approx(40)
    assert m.sample(1001.0)[0] == pytest.approx(50)


def test_frozen_axis_holds_its_position() -> None:
    m = Motion(MotionConfig(kind="ramp", min=0, max=100, speed=10))
    m.start(0.0)
    m.freeze(42)
    assert m.sample(5.0) == (42.0, 0.0)
    m.freeze(None)
    assert m.sample(5.0)[0] == pytest.approx(50)


def test_unknown_motion_keys_are_refused_with_their_names() -> None:
    with pytest.raises(ValueError, match="spede"):
        MotionConfig.from_dict({"spede": 3})


def test_profile_hints_give_range_speed_and_velocity_scale() -> None:
    h = SimHints.from_dict(
        {
            "position_object": "0x6020:01",
            "velocity_object": "0x6030:01",
            "velocity_unit": "mm/s",
            "counts_per_mm": 10,
            "position_range_counts": [0, 10239],
            "typical_speed_mm_s": 200,
        }
    )
    assert (h.motion.min, h.motion.max, h.motion.speed) == (0, 10239, 2000)
    assert h.velocity_scale == pytest.approx(0.1)
    assert str(h.position) == "0x6020:01"
