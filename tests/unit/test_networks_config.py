"""Several CAN networks in one config (``networks:``): the single-network form is one network
named ``default``; each network's sections are checked as a single network's, under its key
path; the refusals are one line each (file, key path, what is allowed)."""

from __future__ import annotations

import copy
import csv
import io
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.cli import main
from canopen_gateway.config import ConfigError
from canopen_gateway.northbound.regmap import build_register_map
from tests.helpers import parse_checked, parse_checked_config, resolved


def node(name: str, node_id: int, **kw: Any) -> dict[str, Any]:
    return {"name": name, "node_id": node_id, "profile": "sgh10", **kw}


def net(name: str, *nodes: dict[str, Any], **kw: Any) -> dict[str, Any]:
    return {"name": name, "can": {"interface": "virtual", "channel": f"t-{name}"},
            "nodes": list(nodes), **kw}  # fmt: skip


TWO = {
    "gateway": {"name": "t"},
    "networks": [
        net("line1", node("wire", 1), master={"node_id": 127, "heartbeat_ms": 500}),
        net("line2", node("drive1", 1, modbus={"unit_id": 101}), master={"node_id": 126}),
    ],
}


def problems(raw: dict[str, Any], environ: dict[str, str] | None = None) -> list[str]:
    with pytest.raises(ConfigError) as exc:  # overrides are applied to a copy: TWO stays as it is
        parse_checked_config(copy.deepcopy(raw), "cfg.yaml", environ=environ or {})
    return exc.value.problems


def test_the_single_network_form_is_one_network_named_default() -> None:
    cfg = parse_checked_config({"can": {"interface": "virtual"}, "nodes": [node("wire", 1)]}, environ={})
    assert cfg.network_names() == ["default"]
    assert cfg.network_view("default") is cfg
    assert cfg.network_of("wire") == "default"


def test_each_network_has_its_own_can_master_and_nodes_and_names_are_gateway_wide() -> None:
    cfg = parse_checked_config(TWO, "cfg.yaml", environ={})
    assert cfg.network_names() == ["line1", "line2"]
    assert [n.name for n in cfg.nodes] == ["wire", "drive1"]
    line2 = cfg.network_view("line2")
    assert (line2.can.channel, line2.master.node_id, [n.name for n in line2.nodes]) == (
        "t-line2", 126, ["drive1"]
    )
    assert cfg.network_of("drive1") == "line2"
    assert line2.qualify("master.heartbeat_ms") == "networks[1].master.heartbeat_ms"


def test_a_config_written_back_reads_as_it_was_written() -> None:
    cfg = parse_checked_config(TWO, "cfg.yaml", environ={})
    again = parse_checked_config(cfg.model_dump(mode="json", exclude_none=True), environ={})
    assert again.network_names() == ["line1", "line2"]
    single = parse_checked_config({"can": {"interface": "virtual"}, "nodes": [node("w", 1)]}, environ={})
    assert "networks" not in single.model_dump()


@pytest.mark.parametrize("key", ["can", "master", "nodes"])
def test_networks_with_a_top_level_key_of_the_single_form_is_refused_naming_both(key: str) -> None:
    value: Any = [] if key == "nodes" else {}
    (line,) = problems({**TWO, key: value})
    assert line.startswith(f"cfg.yaml: {key}: the single-network form's {key}: cannot be given with networks:")


def test_two_networks_of_one_name_are_refused_naming_it() -> None:
    raw = {"networks": [net("line1", node("a", 1)), {**net("line1", node("b", 2)), "can": {"channel": "other"}}]}
    assert problems(raw) == ["cfg.yaml: networks[1].name: duplicate network name 'line1' (also networks[0])"]
    # node 1 on each of the two buses is no clash: only the name is (one line)
    raw["networks"][1]["nodes"] = [{**node("b", 1), "modbus": {"unit_id": 101}}]
    assert problems(raw) == ["cfg.yaml: networks[1].name: duplicate network name 'line1' (also networks[0])"]


def test_a_node_name_twice_in_the_gateway_is_refused_naming_it() -> None:
    raw = {"networks": [net("line1", node("wire", 1)), net("line2", node("wire", 2))]}
    assert problems(raw) == [
        "cfg.yaml: networks[1].nodes[0].name: duplicate name 'wire' (also networks[0].nodes[0]); "
        "node names are unique in the gateway"
    ]


def test_one_node_id_on_two_networks_is_two_devices_but_one_modbus_unit_is_refused() -> None:
    raw = {"networks": [net("line1", node("wire", 1)), net("line2", node("drive1", 1))]}
    assert problems(raw) == [
        "cfg.yaml: networks[1].nodes[0].modbus.unit_id: nodes 'wire' (networks[0].nodes[0]) and "
        "'drive1' (networks[1].nodes[0]) are both on Modbus unit 1 (modbus.unit_id defaults to the "
        "node id): give one of them its own modbus.unit_id"
    ]


def test_a_node_id_twice_on_one_network_is_refused() -> None:
    raw = {"networks": [net("line1", node("a", 1), node("b", 1, modbus={"unit_id": 9}))]}
    assert problems(raw) == ["cfg.yaml: networks[0].nodes[1].node_id: duplicate node_id 1 (also networks[0].nodes[0])"]


def test_two_networks_on_one_bus_are_refused() -> None:
    raw = {"networks": [net("line1", node("a", 1)), {**net("line2", node("b", 2)), "can": {"interface": "virtual", "channel": "t-line1"}}]}
    (line,) = problems(raw)
    assert line.startswith("cfg.yaml: networks[1].can: the same bus as networks[0]")


def test_a_network_name_is_lower_case_letters_digits_dash_and_underscore() -> None:
    (line,) = problems({"networks": [net("Line 1", node("a", 1))]})
    assert line.startswith("cfg.yaml: networks[0].name: got 'Line 1', must match")


def test_the_checks_of_one_bus_run_per_network_under_its_key() -> None:
    """A COB-ID is one bus's: node 1's heartbeat on line1 is no clash with line2's master, a
    master with node 1's id on line2 is, named under networks[1]."""
    raw = {"networks": [
        net("line1", node("a", 1)),
        net("line2", node("c", 1, modbus={"unit_id": 101}), master={"node_id": 1}),
    ]}  # fmt: skip
    (line,) = problems(raw)
    assert line.startswith("cfg.yaml: networks[1].")
    assert "0x701" in line


def test_a_pair_is_checked_per_network() -> None:
    raw = {"networks": [net("line1", node("a", 1), master={"redundancy": {"node_id": 1}})]}
    assert problems(raw) == [
        "cfg.yaml: networks[0].master.redundancy.node_id: 1 is the node id of nodes[0]"
    ]


def test_an_environment_variable_sets_a_key_of_a_network_and_is_blamed() -> None:
    env = {"CANOPEN_GATEWAY__NETWORKS__1__MASTER__NODE_ID": "200"}
    assert problems(TWO, env) == [
        "CANOPEN_GATEWAY__NETWORKS__1__MASTER__NODE_ID: networks[1].master.node_id: got 200, must be <= 127"
    ]


def test_the_register_csv_names_each_points_network_and_the_gateway_block_each_bus() -> None:
    loaded = parse_checked(TWO, "cfg.yaml", environ={})
    rows = list(csv.DictReader(io.StringIO(build_register_map(*loaded).to_csv())))
    assert {r["network"] for r in rows if r["node"] == "drive1"} == {"line2"}
    gateway = {(r["address"], r["signal"], r["network"]) for r in rows if r["unit_id"] == "247"}
    assert {("23", "networks", ""), ("24", "bus_state", "line1"), ("25", "bus_state", "line2"),
            ("32", "pair_role", "line1"), ("33", "pair_role", "line2")} <= gateway  # fmt: skip


def test_each_node_is_resolved_with_its_networks_master() -> None:
    """Supervision settings come from the node's own network's master section."""
    raw = {"networks": [
        net("line1", node("a", 1), master={"heartbeat_timeout_multiple": 2}),
        net("line2", node("b", 1, modbus={"unit_id": 101}), master={"heartbeat_timeout_multiple": 4}),
    ]}  # fmt: skip
    nodes = resolved(parse_checked_config(raw, environ={}))
    assert (nodes["a"].settings.heartbeat_multiple, nodes["b"].settings.heartbeat_multiple) == (2, 4)


TWO_NETWORKS = str(Path(__file__).resolve().parents[2] / "config" / "two-networks.yaml")


def test_the_example_of_two_networks_checks_and_lists_each_networks_nodes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["check", "-c", TWO_NETWORKS]) == 0
    out = capsys.readouterr().out
    assert "network line1 (net 1): virtual two-networks-line1, 500000 bit/s" in out
    assert "network line2 (net 2): virtual two-networks-line2, 250000 bit/s" in out
    assert main(["keys", "-c", TWO_NETWORKS]) == 0
    assert "# node rotary: posi_plus, node id 1, network line2" in capsys.readouterr().out


def test_check_refuses_networks_with_a_top_level_key_before_anything_opens(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "both.yaml"
    f.write_text("can: {interface: virtual}\nnetworks:\n  - {name: line1, can: {interface: virtual}}\n")
    assert main(["check", "-c", str(f)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"{f}: can: the single-network form's can: cannot be given with networks:")


@pytest.mark.parametrize("argv", [["scan"], ["monitor"], ["lss", "inquire"], ["nmt", "start", "wire"],
                                  ["sdo", "read", "wire", "0x1008:00"], ["fault"],
                                  ["decode", "bus.asc"]])  # fmt: skip
def test_a_command_that_opens_a_bus_needs_network_with_several_and_names_them(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "-c", TWO_NETWORKS])
    assert exc.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "the config has 2 networks: give --network NAME (one of: line1, line2)" in line


@pytest.mark.parametrize("argv", [["sdo", "read", "wire", "0x1008:00"], ["nmt", "start", "wire"]])
def test_a_node_asked_for_on_another_network_names_its_own(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "-c", TWO_NETWORKS, "--network", "line2"])
    assert exc.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.endswith("node wire is on network line1, not line2: give --network line1"), line


def test_an_unknown_network_is_refused_with_the_names(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["scan", "-c", TWO_NETWORKS, "--network", "line3"])
    assert "no network named 'line3'; networks: line1, line2" in capsys.readouterr().err


def test_checks_warnings_and_notes_are_each_networks_under_its_key() -> None:
    """A SYNC-driven TPDO without SYNC on its own network is warned of there only (line1 makes
    SYNC, line2 does not); a part of the identity a file cannot give is noted under the node's
    networks[k].nodes[j]."""
    from canopen_gateway.checks import config_notes, config_warnings

    raw = {"networks": [
        net("line1", node("wire", 1), master={"sync_period_ms": 100}),
        net("line2", node("drive1", 1, modbus={"unit_id": 101})),
    ]}  # fmt: skip
    cfg, nodes = parse_checked(raw, "cfg.yaml", environ={})
    warnings = config_warnings(cfg, nodes)
    assert [(k, m.split(":")[0]) for k, m in warnings] == [("networks[1].nodes[0]", "node drive1")]
    assert "TPDO2 is SYNC-driven" in warnings[0][1]
    assert [k for k, _ in config_notes(cfg, nodes)] == [
        "networks[0].nodes[0].identity_check", "networks[1].nodes[0].identity_check"]  # fmt: skip


def test_plc_tag_imports_of_two_networks_keep_their_columns_and_name_each_networks_registers(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Modicon's columns are a fixed interface (no network column: a node's name is unique,
    a network's gateway register says its network in its description); a KEPServerEX tag of
    a network's gateway register carries the network's name, so every tag stays unique."""
    assert main(["registers", "-c", TWO_NETWORKS, "--format", "modicon"]) == 0
    rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert ",".join(rows[0]) == "unit_id,modicon,words,iec_type,word_order,node,signal,unit,description"
    line2_bus = next(r for r in rows if r[:2] == ["247", "300026"])  # input register 25
    assert line2_bus[5:7] == ["(gateway)", "bus_state"] and "network 2 of 2 (line2)" in line2_bus[8]
    assert main(["registers", "-c", TWO_NETWORKS, "--format", "kepware", "--unit", "247"]) == 0
    tags = [r[0] for r in csv.reader(io.StringIO(capsys.readouterr().out))][1:]
    assert len(tags) == len(set(tags))
    assert {"gateway_bus_state", "gateway_line1_bus_state", "gateway_line2_bus_state",
            "gateway_line1_pair_role", "gateway_line2_pair_role"} <= set(tags)  # fmt: skip
    assert main(["registers", "-c", TWO_NETWORKS, "--csv", "--unit", "101"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert rows and {r["network"] for r in rows} == {"line2"}  # one unit's listing keeps the column
