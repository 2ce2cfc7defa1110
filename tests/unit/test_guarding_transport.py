"""Node guarding needs remote frames: on ``interface: socketcand`` (whose ASCII protocol has no
remote frame) a guarded node is a warning of ``check`` naming the node and the way out."""

from __future__ import annotations

from canopen_gateway.checks import config_warnings
from tests.helpers import make_config, resolved

GUARDED = {"name": "wire", "node_id": 1, "profile": "sgh10", "supervision": "guarding"}


def _warnings(node: dict, can: dict) -> list[tuple[str, str]]:
    cfg = make_config([node], can=can)
    return [w for w in config_warnings(cfg, resolved(cfg)) if "remote frames" in w[1]]


def test_a_guarded_node_on_socketcand_is_a_warning_naming_the_node_and_the_fix() -> None:
    can = {"interface": "socketcand", "host": "127.0.0.1", "port": 29536, "channel": "can0"}
    (key, text), = _warnings(GUARDED, can)
    assert key == "nodes[0].supervision"
    assert text.startswith("node wire: node guarding needs remote frames (RTR)")
    assert "supervision: heartbeat" in text


def test_heartbeat_on_socketcand_and_guarding_elsewhere_say_nothing() -> None:
    can = {"interface": "socketcand", "host": "127.0.0.1", "port": 29536, "channel": "can0"}
    assert _warnings({**GUARDED, "supervision": "heartbeat"}, can) == []
    assert _warnings(GUARDED, {"interface": "virtual"}) == []
