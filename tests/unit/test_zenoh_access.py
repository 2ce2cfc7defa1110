"""``zenoh.writes`` and ``zenoh.write_allow``: the decision table of ``WriteGate``, and the
configuration errors (file, key path, what is allowed)."""

from __future__ import annotations

import pytest

from canopen_gateway.config import ConfigError, ZenohSection
from canopen_gateway.zenoh_bridge.access import WriteGate
from tests.helpers import make_config

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
P = "canopen/line1"


def gate(**section: object) -> WriteGate:
    return WriteGate(ZenohSection.model_validate(section))


def test_writes_are_off_by_default_and_every_operation_is_refused() -> None:
    g = gate()
    for op in ("set", "sdo_write", "nmt"):
        why = g.refusal(op, "wire", f"{P}/wire/x")
        assert why is not None and "zenoh.writes: on" in why


def test_writes_on_without_rules_allow_everything() -> None:
    g = gate(writes=True)
    assert all(g.refusal(op, "n", f"{P}/n/x") is None for op in ("set", "sdo_write", "nmt"))


def test_a_rule_matches_when_operation_node_and_key_all_match() -> None:
    g = gate(
        writes=True,
        write_allow=[
            {"operations": ["set"], "nodes": ["display"], "keys": [f"{P}/display/set/set_point$*"]},
            {"operations": ["nmt"]},
        ],
    )
    assert g.refusal("set", "display", f"{P}/display/set/set_point2") is None
    assert g.refusal("set", "display", f"{P}/display/set/control_word") is not None
    assert g.refusal("set", "wire", f"{P}/wire/set/set_point2") is not None
    assert g.refusal("sdo_write", "display", f"{P}/display/set/set_point2") is not None
    assert g.refusal("nmt", "wire", f"{P}/wire/nmt") is None
    assert "zenoh.write_allow" in (g.refusal("sdo_write", "wire", f"{P}/wire/sdo/1/0") or "")


def test_yaml_on_and_off_are_the_writes_switch() -> None:
    assert ZenohSection.model_validate({"writes": "on"}).writes is True
    assert ZenohSection.model_validate({"writes": "off"}).writes is False


@pytest.mark.parametrize(
    "zenoh,where,words",
    [
        ({"write_allow": [{"operations": ["set"]}]}, "zenoh", "writes is off"),
        ({"writes": True, "write_allow": [{"operations": ["jump"]}]},
         "zenoh.write_allow[0].operations[0]", "'set', 'sdo_write' or 'nmt'"),
        ({"writes": True, "write_allow": [{"nodes": ["ghost"]}]},
         "zenoh.write_allow[0].nodes[0]", "no node named 'ghost'"),
        ({"writes": True, "write_allow": [{"keys": ["a//b"]}]},
         "zenoh.write_allow[0]", "empty chunk"),
        ({"auth": {"user": "gw"}}, "zenoh.auth", "has no password"),
        ({"auth": {"password": "x"}}, "zenoh.auth", "user is missing"),
        ({"auth": {"user": "gw", "password": "x", "password_file": "f"}}, "zenoh.auth", "not both"),
        ({"history": {"events": -1}}, "zenoh.history.events", ">= 0"),
        ({"prefix": "canopen/*"}, "zenoh", "no wildcards"),
    ],
)  # fmt: skip
def test_config_errors_name_the_key_and_what_is_allowed(
    zenoh: dict[str, object], where: str, words: str
) -> None:
    with pytest.raises(ConfigError) as exc:
        make_config([WIRE], zenoh=zenoh)
    lines = [p for p in exc.value.problems if f": {where}: " in p]
    assert lines and words in lines[0], exc.value.problems
