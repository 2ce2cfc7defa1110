"""Safe outputs resolved from a profile overlay's ``safe_value`` and the node's
``safe_outputs`` (which wins), and the lines ``check`` prints for wrong ones."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.config import ConfigError
from canopen_gateway.modbus.safe_outputs import safe_outputs
from canopen_gateway.profiles import load_node_profile
from tests.helpers import parse_checked_config

IO = Path(__file__).resolve().parents[1] / "data" / "eds" / "io401.eds"


def overlay(tmp_path: Path, body: str) -> str:
    p = tmp_path / "io.yaml"
    p.write_text(f"family: io\neds: {IO}\n{body}", encoding="utf-8")
    return str(p)


def config(nodes: list[dict[str, Any]]) -> Any:
    raw = {"can": {"interface": "virtual", "channel": "x"}, "nodes": nodes}
    return parse_checked_config(raw, "cfg.yaml", environ={})


def test_profile_safe_value_and_node_override(tmp_path: Path) -> None:
    prof = overlay(
        tmp_path,
        "signals:\n"
        "  - {name: dout, object: '0x6200:01', safe_value: 0x0F}\n"
        "  - {name: aout, object: '0x6411:01', safe_value: -5}\n",
    )
    cfg = config([{"name": "io", "node_id": 5, "profile": prof, "safe_outputs": {"aout": 7}}])
    node = cfg.nodes[0]
    assert safe_outputs(load_node_profile(node.setup, cfg.base_dir), node) == {"dout": 0x0F, "aout": 7}


def test_check_names_a_profile_safe_value_out_of_range(tmp_path: Path) -> None:
    prof = overlay(tmp_path, "signals:\n  - {name: dout, object: '0x6200:01', safe_value: 256}\n")
    with pytest.raises(ConfigError) as err:
        config([{"name": "io", "node_id": 5, "profile": prof}])
    assert err.value.problems == [
        "cfg.yaml: nodes[0] (profile io).signals.dout.safe_value: value 256 not allowed, "
        "expected 0..255 (uint8)"
    ]


def test_a_node_without_safe_values_has_none() -> None:
    cfg = config([{"name": "io", "node_id": 5, "eds": str(IO)}])
    node = cfg.nodes[0]
    assert safe_outputs(load_node_profile(node.setup, cfg.base_dir), node) == {}
