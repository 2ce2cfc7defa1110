"""Configuration errors: one line per problem naming the file, the key path and what is allowed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from canopen_gateway.config import ConfigError
from tests.helpers import load_checked_config as load_config
from tests.helpers import parse_checked_config as parse_config

GOOD = {
    "gateway": {"name": "t"},
    "can": {"interface": "virtual", "channel": "x"},
    "nodes": [
        {"name": "wire", "node_id": 1, "profile": "sgh10"},
        {"name": "display", "node_id": 125, "profile": "ap05"},
    ],
}


def problems(raw: dict, environ: dict | None = None) -> list[str]:
    with pytest.raises(ConfigError) as exc:
        parse_config(raw, "cfg.yaml", environ=environ or {})
    return exc.value.problems


def with_nodes(*nodes: dict, **extra: object) -> dict:
    return {**GOOD, "nodes": list(nodes), **extra}


def test_good_config_loads() -> None:
    cfg = parse_config(GOOD, "cfg.yaml", environ={})
    assert [n.name for n in cfg.nodes] == ["wire", "display"]
    assert cfg.zenoh.key_prefix(cfg.gateway.name) == "canopen/t"


def test_values_of_one_millisecond_go_out_together_by_default() -> None:
    """docs/zenoh.md: ``zenoh.batch_ms`` defaults to 1; 0 publishes at the end of every burst."""
    assert parse_config(GOOD, "cfg.yaml", environ={}).zenoh.batch_ms == 1.0
    per_burst = parse_config({**GOOD, "zenoh": {"batch_ms": 0}}, "cfg.yaml", environ={})
    assert per_burst.zenoh.batch_ms == 0.0


def test_unknown_key_is_reported_with_its_path() -> None:
    p = problems(with_nodes({"name": "wire", "node_idd": 1, "profile": "sgh10"}))
    assert "cfg.yaml: nodes[0].node_idd: unknown key (typo?); did you mean 'node_id'?" in p


def test_unknown_section_is_reported() -> None:
    p = problems({**GOOD, "modbuss": {"port": 1}})
    assert "cfg.yaml: modbuss: unknown key (typo?); did you mean 'modbus'?" in p


def test_wrong_type_is_reported() -> None:
    p = problems({**GOOD, "modbus": {"port": "five"}})
    assert any(line.startswith("cfg.yaml: modbus.port: ") for line in p)


def test_out_of_range_node_id_says_what_is_allowed() -> None:
    p = problems(with_nodes({"name": "wire", "node_id": 128, "profile": "sgh10"}))
    assert "cfg.yaml: nodes[0].node_id: got 128, must be <= 127" in p


def test_duplicate_node_id_names_both_entries() -> None:
    p = problems(
        with_nodes(
            {"name": "a", "node_id": 1, "profile": "sgh10"},
            {"name": "b", "node_id": 1, "profile": "sgh10", "modbus": {"unit_id": 9}},
        )
    )
    assert "cfg.yaml: nodes[1].node_id: duplicate node_id 1 (also nodes[0])" in p


def test_duplicate_name_is_reported() -> None:
    p = problems(
        with_nodes(
            {"name": "a", "node_id": 1, "profile": "sgh10"},
            {"name": "a", "node_id": 2, "profile": "sgh10"},
        )
    )
    assert "cfg.yaml: nodes[1].name: duplicate name 'a' (also nodes[0])" in p


def test_duplicate_modbus_unit_id_is_reported() -> None:
    p = problems(
        with_nodes(
            {"name": "a", "node_id": 1, "profile": "sgh10"},
            {"name": "b", "node_id": 2, "profile": "sgh10", "modbus": {"unit_id": 1}},
        )
    )
    assert "cfg.yaml: nodes[1].modbus.unit_id: duplicate Modbus unit id 1 (also nodes[0])" in p


def test_unknown_profile_lists_the_built_in_ones() -> None:
    p = problems(with_nodes({"name": "a", "node_id": 1, "profile": "sgh11"}))
    line = next(x for x in p if x.startswith("cfg.yaml: nodes[0].profile: "))
    assert "unknown profile 'sgh11'" in line and "sgh10" in line and "ap05" in line


def test_missing_profile_file_is_reported(tmp_path: Path) -> None:
    p = problems(with_nodes({"name": "a", "node_id": 1, "profile": str(tmp_path / "nope.yaml")}))
    assert any("nodes[0].profile" in x and "does not exist" in x for x in p)


def test_register_address_collision_is_reported() -> None:
    p = problems(
        with_nodes(
            {
                "name": "wire",
                "node_id": 1,
                "profile": "sgh10",
                "signals": {"velocity": {"address": 100}},
            }
        )
    )
    assert any("used twice" in x and "position" in x and "velocity" in x for x in p), p


def test_unknown_signal_override_is_reported() -> None:
    p = problems(
        with_nodes({"name": "wire", "node_id": 1, "profile": "sgh10", "signals": {"posit": {}}})
    )
    assert any(x.startswith("cfg.yaml: nodes[0].signals.posit: profile sgh10 has no signal") for x in p)


def test_typo_and_duplicate_are_both_reported_at_once() -> None:
    p = problems(
        with_nodes(
            {"name": "a", "node_id": 1, "profile": "sgh10", "heartbeat_msec": 100},
            {"name": "b", "node_id": 1, "profile": "sgh10", "modbus": {"unit_id": 3}},
        )
    )
    assert "cfg.yaml: nodes[0].heartbeat_msec: unknown key (typo?); did you mean 'heartbeat_ms'?" in p
    assert "cfg.yaml: nodes[1].node_id: duplicate node_id 1 (also nodes[0])" in p


def test_missing_file_is_reported(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as exc:
        load_config(tmp_path / "absent.yaml", environ={})
    assert exc.value.problems == [f"{tmp_path / 'absent.yaml'}: file does not exist"]


def test_yaml_syntax_error_names_the_line(tmp_path: Path) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text("gateway:\n  name: [unclosed\n")
    with pytest.raises(ConfigError) as exc:
        load_config(f, environ={})
    assert "YAML syntax error" in exc.value.problems[0] and "line" in exc.value.problems[0]


def test_a_missing_colon_is_reported_at_its_own_line_and_quoted(tmp_path: Path) -> None:
    """``port 5020`` without its colon: PyYAML gives up two lines later (at the next key); the
    error points at the line of the mistake and quotes it."""
    f = tmp_path / "plant.yaml"
    f.write_text(
        "can:\n  interface: virtual\n  channel: plant\n"
        "modbus:\n  host: 127.0.0.1\n  port 5020\n\nzenoh:\n  mode: peer\n"
    )
    with pytest.raises(ConfigError) as exc:
        load_config(f, environ={})
    assert exc.value.problems == [
        f"{f}: line 6, column 3: YAML syntax error: could not find expected ':' "
        "(while scanning a simple key): 'port 5020'"
    ]


def test_an_unclosed_bracket_is_reported_where_it_opens(tmp_path: Path) -> None:
    f = tmp_path / "plant.yaml"
    f.write_text("zenoh:\n  listen: [tcp/127.0.0.1:7447\nmodbus:\n  port: 5020\n")
    with pytest.raises(ConfigError) as exc:
        load_config(f, environ={})
    (line,) = exc.value.problems
    assert line.startswith(f"{f}: line 2, column 11: YAML syntax error: ")
    assert line.endswith("(while parsing a flow sequence): 'listen: [tcp/127.0.0.1:7447'")


def test_environment_overrides_a_single_key() -> None:
    cfg = parse_config(
        {**GOOD, "nodes": [dict(n) for n in GOOD["nodes"]]},
        "cfg.yaml",
        environ={
            "CANOPEN_GATEWAY__MODBUS__PORT": "502",
            "CANOPEN_GATEWAY__NODES__0__NODE_ID": "5",
            "CANOPEN_GATEWAY__ZENOH__CONNECT": '["tcp/router:7447"]',
        },
    )
    assert cfg.modbus.port == 502
    assert cfg.nodes[0].node_id == 5
    assert cfg.zenoh.connect == ["tcp/router:7447"]


def test_environment_override_to_missing_list_item_is_reported() -> None:
    p = problems(
        {**GOOD, "nodes": [dict(n) for n in GOOD["nodes"]]},
        environ={"CANOPEN_GATEWAY__NODES__7__NODE_ID": "5"},
    )
    assert "CANOPEN_GATEWAY__NODES__7__NODE_ID: nodes[7].node_id: no list item 7 (nodes has 2 items)" in p


def test_an_unknown_section_from_the_environment_is_blamed_on_the_variable() -> None:
    """``NODE`` for ``NODES``: the file has no ``node:`` section; the variable wrote it."""
    p = problems(
        {**GOOD, "nodes": [dict(n) for n in GOOD["nodes"]]},
        environ={"CANOPEN_GATEWAY__NODE__0__NODE_ID": "5"},
    )
    assert p == ["CANOPEN_GATEWAY__NODE__0__NODE_ID: node: unknown key (typo?); did you mean 'nodes'?"]


def test_an_unknown_key_written_in_the_file_is_still_the_file_s() -> None:
    p = problems(
        {**GOOD, "modbuss": {"port": 1}},
        environ={"CANOPEN_GATEWAY__MODBUS__PORT": "502"},
    )
    assert "cfg.yaml: modbuss: unknown key (typo?); did you mean 'modbus'?" in p


def test_a_value_that_is_not_valid_yaml_says_so_naming_the_variable() -> None:
    p = problems(GOOD, environ={"CANOPEN_GATEWAY__ZENOH__CONNECT": '["tcp/router:7447"'})
    assert len(p) == 1, p
    assert p[0].startswith("CANOPEN_GATEWAY__ZENOH__CONNECT: zenoh.connect: not valid YAML ("), p
    assert "valid list" not in p[0]


def test_external_heartbeat_slower_sync_is_rejected() -> None:
    p = problems(
        with_nodes(
            {
                "name": "display",
                "node_id": 125,
                "profile": "ap05",
                "external_heartbeat": {"interval_ms": 100, "source": "sync"},
            },
            master={"sync_period_ms": 200},
        )
    )
    assert any(x.startswith("cfg.yaml: master.sync_period_ms: SYNC every 200 ms") for x in p), p


def test_check_prints_every_problem_of_the_readme_example_in_one_run(tmp_path: Path) -> None:
    """README "Configuration": a typo in a node, a duplicate node id, a typo in can: and one in
    an environment variable are all printed by one ``check``, each blamed on who wrote it."""
    f = tmp_path / "bad.yaml"
    f.write_text(
        "can: {interface: virtual, chanel: x}\n"
        "nodes:\n"
        "  - {name: a, node_id: 1, profile: sgh10}\n"
        "  - {name: b, node_idd: 2, profile: sgh10}\n"
        "  - {name: c, node_id: 1, profile: sgh10}\n"
    )
    env = {**os.environ, "CANOPEN_GATEWAY__MODBUS__PROT": "5020"}
    r = subprocess.run(
        [sys.executable, "-m", "canopen_gateway", "check", "-c", str(f)],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert f"{f}: nodes[1].node_idd: unknown key (typo?); did you mean 'node_id'?" in lines
    assert f"{f}: nodes[2].node_id: duplicate node_id 1 (also nodes[0])" in lines
    assert any(x.startswith(f"{f}: can.chanel: unknown key for interface 'virtual' (did you mean 'channel'?") for x in lines), lines
    assert "CANOPEN_GATEWAY__MODBUS__PROT: modbus.prot: unknown key (typo?); did you mean 'port'?" in lines


def test_a_cross_check_of_a_value_the_environment_set_blames_the_variable() -> None:
    # README: a value set by an environment variable is blamed on the variable, also for the
    # checks across sections (here the flat register layout's stride)
    env = {"CANOPEN_GATEWAY__MODBUS__LAYOUT": "flat", "CANOPEN_GATEWAY__MODBUS__FLAT_STRIDE": "100"}
    with pytest.raises(ConfigError) as exc:
        parse_config({**GOOD}, "cfg.yaml", environ=env)
    assert any(
        x.startswith("CANOPEN_GATEWAY__MODBUS__FLAT_STRIDE: modbus.flat_stride: ") for x in exc.value.problems
    ), exc.value.problems


def test_external_heartbeat_the_gateway_cannot_feed_is_rejected_with_its_key() -> None:
    # AP05 manual 5.5.4: no RPDO / SYNC within 5F09h:01 and the device drops to pre-operational
    def display(**eh: object) -> dict:
        return {"name": "display", "node_id": 125, "profile": "ap05", "external_heartbeat": eh}

    p = problems(with_nodes(display(interval_ms=100, source="sync")))
    assert "cfg.yaml: nodes[0].external_heartbeat.source: source sync needs master.sync_period_ms > 0" in p
    p = problems(with_nodes(display(interval_ms=100, keepalive_ms=100)))
    assert (
        "cfg.yaml: nodes[0].external_heartbeat.keepalive_ms: keep-alive every 100 ms cannot feed "
        "an external heartbeat of 100 ms; must be below 100 ms"
    ) in p
    parse_config(with_nodes(display(interval_ms=100, keepalive_ms=40)), "cfg.yaml", environ={})
    synced = with_nodes(display(interval_ms=100, source="sync"), master={"sync_period_ms": 50})
    parse_config(synced, "cfg.yaml", environ={})


def test_cli_check_prints_problems_and_exits_2(tmp_path: Path) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text(
        "nodes:\n"
        "  - {name: a, node_id: 1, profile: sgh10, nodeid: 3}\n"
        "  - {name: b, node_id: 1, profile: sgh10, modbus: {unit_id: 4}}\n"
    )
    r = subprocess.run(
        [sys.executable, "-m", "canopen_gateway", "check", "-c", str(f)], capture_output=True, text=True
    )
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert f"{f}: nodes[0].nodeid: unknown key (typo?); did you mean 'node_id'?" in lines
    assert f"{f}: nodes[1].node_id: duplicate node_id 1 (also nodes[0])" in lines


def test_example_configs_pass_check() -> None:
    root = Path(__file__).resolve().parents[2]
    for name in ("demo.yaml", "plant-example.yaml"):
        load_config(root / "config" / name, environ={})
