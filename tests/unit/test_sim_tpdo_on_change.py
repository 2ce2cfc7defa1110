"""Change-driven TPDOs of a simulated device known only from its file (types 254/255 without
event timer): sent when their data change, sampled every ``input_cycle_ms``, never two frames
closer than the inhibit time 1800h:03 (a change inside it goes out when it ends). Device:
tests/data/eds/compact.dcf (TPDO2 = 2100h:00, type 255, no event timer, inhibit 200 x 100 us),
driven with raw frames and a fake clock."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.profiles import load_node_profile
from canopen_gateway.sim.node import SimNode
from tests.helpers import frame, make_config, simulated_bus

DCF = Path(__file__).resolve().parents[1] / "data" / "eds" / "compact.dcf"
NODE = 10
TPDO2 = 0x280 + NODE


def started(inhibit_100us: int | None = None, **options: Any) -> SimNode:
    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(DCF)}])
    node = SimNode(load_node_profile(cfg.nodes[0].setup, cfg.base_dir), NODE, options=options)
    node.power_on(0.0)
    if inhibit_100us is not None:
        node.set(0x1801, 3, inhibit_100us)
    node.handle(frame(0x000, f"01 {NODE:02X}"), 0.0)
    return node


def run(node: SimNode, until_ms: int) -> list[tuple[int, int, int]]:
    """(time ms, counter the frame carries, counter an SDO read gives at that time) of each
    TPDO2 frame while ticking every millisecond."""
    out = []
    for ms in range(until_ms + 1):
        for m in node.tick(ms / 1000):
            if m.arbitration_id == TPDO2:
                out.append((ms, int.from_bytes(m.data, "little"), node.sdo_read_local("0x2100:00")))
    return out


def test_a_change_driven_tpdo_follows_its_value_at_each_input_sample() -> None:
    sent = run(started(inhibit_100us=0), 100)
    assert [ms for ms, _, _ in sent] == list(range(0, 101, 10))  # default input cycle 10 ms
    assert all(carried == held for _, carried, held in sent)
    assert len({carried for _, carried, _ in sent}) == len(sent)  # each frame: a new value


def test_without_a_change_nothing_more_is_sent() -> None:
    sent = run(started(inhibit_100us=0, motion={"kind": "hold", "hold": 4526}), 1000)
    assert [(ms, carried) for ms, carried, _ in sent] == [(0, 4526 + 14)]  # 2100h: third input


def test_the_inhibit_time_spaces_the_frames_and_a_held_back_change_goes_out_when_it_ends() -> None:
    # inputs sampled every 10 ms, each sample a new value; inhibit 15 ms: the change seen at
    # 10 ms goes out at 15 ms (the end of the window), the one seen at 20 ms at 30 ms...
    sent = run(started(inhibit_100us=150), 100)
    assert [ms for ms, _, _ in sent] == [0, 15, 30, 45, 60, 75, 90]
    assert all(carried == held for _, carried, held in sent)


def test_while_a_change_waits_the_next_deadline_is_the_end_of_the_inhibit_window() -> None:
    node = started(inhibit_100us=150)
    assert [m.arbitration_id for m in node.tick(0.0)].count(TPDO2) == 1
    assert [m.arbitration_id for m in node.tick(0.010)].count(TPDO2) == 0  # held back
    assert node.next_deadline(0.010) == pytest.approx(0.015)
    assert [m.arbitration_id for m in node.tick(0.015)].count(TPDO2) == 1


def test_a_change_driven_tpdo_goes_out_only_in_operational() -> None:
    node = started(inhibit_100us=0)
    assert run(node, 20)
    node.handle(frame(0x000, f"80 {NODE:02X}"), 0.021)  # PRE-OPERATIONAL
    assert [m for ms in range(22, 60) for m in node.tick(ms / 1000) if m.arbitration_id == TPDO2] == []


@pytest.mark.parametrize(
    ("section", "value", "message"),
    [
        ("options", {"input_cycle_ms": 0}, "<memory>: simulate.options.io: input_cycle_ms: 0 is not a number of ms above 0"),
        ("options", {"input_cycle_ms": "fast"}, "<memory>: simulate.options.io: input_cycle_ms: 'fast' is not a number of ms above 0"),
        ("motion", {"kind": "bogus"}, "<memory>: simulate.motion.io: motion kind 'bogus' is not ramp, sine, random_walk or hold"),
    ],
)  # fmt: skip
def test_a_simulator_option_it_refuses_is_a_config_error_naming_its_key(
    section: str, value: dict[str, Any], message: str
) -> None:
    from canopen_gateway.config import ConfigError

    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(DCF)}], simulate={section: {"io": value}})
    with pytest.raises(ConfigError) as err:
        simulated_bus(cfg)
    assert err.value.problems == [message]
