"""``canopen-gateway check -c A.yaml -c B.yaml``: the two configs of a hot-standby pair are
each checked as at every start, then compared: the same bus, logical master, nodes and
register layout; both with ``master.redundancy``, distinct own ids, ``peer_node_id`` naming
the other. Every difference is one line naming both files and the key path."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from canopen_gateway.checks import config_warnings, pair_problems
from canopen_gateway.config import ConfigError
from tests.helpers import parse_checked_config as parse_config
from tests.helpers import resolved

ROOT = Path(__file__).resolve().parents[2]


def raw_pair() -> tuple[dict[str, Any], dict[str, Any]]:
    raw: dict[str, Any] = {
        "can": {"interface": "remote", "channel": "ws://127.0.0.1:54701/", "bitrate": 500000},
        "master": {
            "node_id": 100,
            "heartbeat_ms": 100,
            "sync_period_ms": 50,
            "redundancy": {"node_id": 101, "priority": 0, "peer_node_id": 102},
        },
        "nodes": [
            {"name": "wire", "node_id": 1, "profile": "sgh10", "modbus": {"unit_id": 1}},
            {"name": "display", "node_id": 2, "profile": "ap05"},
        ],
        "modbus": {"port": 5020},
    }
    b = copy.deepcopy(raw)
    b["master"]["redundancy"] = {"node_id": 102, "priority": 1, "peer_node_id": 101}
    b["modbus"]["port"] = 5021  # a gateway's own listening ports may differ
    return raw, b


def problems(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    cfg_a, cfg_b = parse_config(a, "A.yaml", {}), parse_config(b, "B.yaml", {})
    return pair_problems(cfg_a, cfg_b, resolved(cfg_a), resolved(cfg_b))


def test_two_configs_of_one_pair_agree() -> None:
    assert problems(*raw_pair()) == []


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (lambda b: b["can"].update(channel="ws://127.0.0.1:54702/"), "can.channel"),
        (lambda b: b["can"].update(interface="socketcan"), "can.interface"),
        (lambda b: b["can"].update(bitrate=250000), "can.bitrate"),
        (lambda b: b["master"].update(node_id=99), "master.node_id"),
        (lambda b: b["master"].update(heartbeat_ms=200), "master.heartbeat_ms"),
        (lambda b: b["master"].update(sync_period_ms=0), "master.sync_period_ms"),
        (lambda b: b["master"]["redundancy"].update(priority_slot_ms=100), "master.redundancy.priority_slot_ms"),
        (lambda b: b["nodes"][0].update(node_id=3), "nodes[0].node_id"),
        (lambda b: b["nodes"][0]["modbus"].update(unit_id=7), "nodes[0].modbus.unit_id"),
        (lambda b: b["nodes"][0].update(heartbeat_ms=500), "nodes[0].heartbeat_ms"),
        (lambda b: b["modbus"].update(layout="flat"), "modbus.layout"),
    ],
)
def test_a_shared_setting_that_differs_is_one_line_naming_both_files_and_the_key(change: Any, key: str) -> None:
    a, b = raw_pair()
    change(b)
    lines = problems(a, b)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"A.yaml, B.yaml: {key}: ")
    assert "in A.yaml" in lines[0] and "in B.yaml" in lines[0]


def test_a_node_of_one_config_only_is_named() -> None:
    a, b = raw_pair()
    b["nodes"].pop(1)
    assert problems(a, b) == ["A.yaml, B.yaml: nodes[1]: node display only in A.yaml"]
    assert problems(b, a) == ["A.yaml, B.yaml: nodes[1]: node display only in B.yaml"]


def test_nodes_in_another_order_are_compared_by_name() -> None:
    a, b = raw_pair()
    b["nodes"].reverse()
    assert problems(a, b) == []
    b["nodes"][0]["node_id"] = 5  # display, nodes[1] in A
    assert problems(a, b) == [
        "A.yaml, B.yaml: nodes[1] (display, nodes[0] in B.yaml).node_id: 2 in A.yaml, 5 in B.yaml: a pair must agree"
    ]


def test_another_profile_for_a_node_is_named() -> None:
    a, b = raw_pair()
    b["nodes"][0]["profile"] = "ap05"
    lines = problems(a, b)
    assert any(line.startswith("A.yaml, B.yaml: nodes[0].profile: the device descriptions differ") for line in lines)
    assert any(line.startswith("A.yaml, B.yaml: nodes[0].profile: the profiles differ") for line in lines)


def test_both_need_redundancy() -> None:
    a, b = raw_pair()
    del b["master"]["redundancy"]
    lines = problems(a, b)
    assert "A.yaml, B.yaml: master.redundancy: missing in B.yaml: both configs of a pair need it" in lines


def test_the_two_own_ids_must_differ() -> None:
    a, b = raw_pair()
    for raw in (a, b):
        raw["master"]["redundancy"] = {"node_id": 101}
    assert problems(a, b) == [
        "A.yaml, B.yaml: master.redundancy.node_id: 101 in both: each gateway needs its own id"
    ]


def test_peer_node_id_must_name_the_other_gateway() -> None:
    a, b = raw_pair()
    a["master"]["redundancy"]["peer_node_id"] = 103
    assert problems(a, b) == [
        "A.yaml, B.yaml: master.redundancy.peer_node_id: 103 in A.yaml, but the other "
        "gateway's master.redundancy.node_id is 102"
    ]


def test_own_settings_may_differ() -> None:
    a, b = raw_pair()
    b["master"]["redundancy"]["takeover_ms"] = 400
    b["gateway"] = {"name": "line1-b"}
    b["zenoh"] = {"listen": ["tcp/127.0.0.1:7448"]}
    assert problems(a, b) == []


def _run_check(*paths: Path) -> subprocess.CompletedProcess[str]:
    args = [a for p in paths for a in ("-c", str(p))]
    return subprocess.run(
        [sys.executable, "-m", "canopen_gateway", "check", *args], capture_output=True, text=True, cwd=ROOT
    )


def test_cli_check_of_two_configs_exits_2_with_one_line_per_difference(tmp_path: Path) -> None:
    a, b = raw_pair()
    fa, fb = tmp_path / "A.yaml", tmp_path / "B.yaml"
    fa.write_text(yaml.safe_dump(a))
    fb.write_text(yaml.safe_dump(b))
    ok = _run_check(fa, fb)
    assert ok.returncode == 0, ok.stderr
    assert f"{fa}: OK" in ok.stdout and f"{fb}: OK" in ok.stdout
    b["master"]["heartbeat_ms"] = 200
    a["master"]["redundancy"]["peer_node_id"] = 103
    fa.write_text(yaml.safe_dump(a))
    fb.write_text(yaml.safe_dump(b))
    bad = _run_check(fa, fb)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [
        f"{fa}, {fb}: master.heartbeat_ms: 100 in {fa}, 200 in {fb}: a pair must agree",
        f"{fa}, {fb}: master.redundancy.peer_node_id: 103 in {fa}, but the other gateway's "
        "master.redundancy.node_id is 102",
    ]


def test_cli_check_of_a_pair_says_the_problems_of_each_file_first(tmp_path: Path) -> None:
    a, b = raw_pair()
    b["master"]["redundancy"]["node_id"] = 1  # a node's id
    fa, fb = tmp_path / "A.yaml", tmp_path / "B.yaml"
    fa.write_text(yaml.safe_dump(a))
    fb.write_text(yaml.safe_dump(b))
    bad = _run_check(fa, fb)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [
        f"{fb}: master.redundancy.node_id: 1 is the node id of nodes[0]"
    ]


# --------------------------------------------------------------------------- a bus to share


def test_a_bus_two_processes_cannot_share_is_refused_naming_what_to_use() -> None:
    a, b = raw_pair()
    for raw in (a, b):
        raw["can"] = {"interface": "virtual", "channel": "line1"}
    (line,) = problems(a, b)
    assert line.startswith("A.yaml, B.yaml: can.interface: 'virtual' in A.yaml is each process's own")
    assert "interface: remote" in line and "socketcand" in line and "socketcan" in line


# --------------------------------------------------------------------------- the take-over's worst case
# hb 100 ms, takeover_ms default 300; A: priority 0, id 101: 300 + 0 + 202 + 100 = 602 ms;
# B: priority 1, id 102: 300 + 200 + 204 + 100 = 804 ms


def warnings(raw: dict[str, Any], source: str) -> list[tuple[str, str]]:
    cfg = parse_config(raw, source, {})
    return config_warnings(cfg, resolved(cfg))


def test_takeover_ms_under_two_logical_heartbeats_is_refused_naming_the_key() -> None:
    a, _ = raw_pair()
    a["master"]["redundancy"]["takeover_ms"] = 199
    with pytest.raises(ConfigError) as exc:
        parse_config(a, "A.yaml", {})
    (line,) = exc.value.problems
    assert line.startswith("A.yaml: master.redundancy.takeover_ms: 199 ms is under two logical heartbeats")
    assert "at least 200 ms" in line
    a["master"]["redundancy"]["takeover_ms"] = 200
    parse_config(a, "A.yaml", {})  # two heartbeats: accepted


def test_a_guarded_node_whose_life_time_a_takeover_outlasts_is_a_warning_naming_both_times() -> None:
    a, b = raw_pair()
    for raw in (a, b):
        raw["nodes"][0].update(supervision="guarding", guard_time_ms=100, life_time_factor=7)
    assert [w for w in warnings(a, "A.yaml") if "life time" in w[1]] == []  # 700 >= 602
    ((key, text),) = [w for w in warnings(b, "B.yaml") if "life time" in w[1]]
    assert key == "nodes[0].guard_time_ms"
    assert text.startswith("node wire: node guarding life time 100 ms x 7 = 700 ms is shorter than")
    assert "the worst take-over by this gateway (redundancy.node_id 102), 804 ms" in text
    assert "at least 804 ms, or supervise it by heartbeat" in text


def test_a_boot_step_writing_a_shorter_consumer_of_the_logical_heartbeat_is_a_warning() -> None:
    a, _ = raw_pair()

    def consumer(value: int) -> list[tuple[str, str]]:
        a["nodes"] = [{"name": "enc", "node_id": 3, "profile": "posi_plus", "sdo": [{"object": "0x1016:01", "value": value}]}]
        return [w for w in warnings(a, "A.yaml") if "consumer" in w[1]]

    ((key, text),) = consumer((100 << 16) | 500)
    assert key == "nodes[0].sdo"
    assert "node enc: boot step 0x1016:01 sets its consumer of the logical master's heartbeat" in text
    assert "(node 100) to 500 ms, shorter than the worst take-over" in text and "602 ms" in text
    assert consumer((100 << 16) | 1000) == []
    assert consumer((5 << 16) | 200) == []  # another producer's heartbeat


def test_cli_check_of_a_pair_prints_the_takeover_warning_of_the_slower_member(tmp_path: Path) -> None:
    a, b = raw_pair()
    for raw in (a, b):
        raw["nodes"][0].update(supervision="guarding", guard_time_ms=100, life_time_factor=7)
    fa, fb = tmp_path / "A.yaml", tmp_path / "B.yaml"
    fa.write_text(yaml.safe_dump(a))
    fb.write_text(yaml.safe_dump(b))
    ok = _run_check(fa, fb)
    assert ok.returncode == 0, ok.stderr
    lines = [line for line in ok.stdout.splitlines() if "life time" in line]
    assert len(lines) == 1 and "804 ms" in lines[0] and lines[0].startswith("  warning: node wire:")
    assert "shorter than the worst take-over by this gateway (redundancy.node_id 102), 804 ms = " in lines[0]
    figures = [line for line in ok.stdout.splitlines() if line.startswith("  hot-standby pair:")]
    assert [f.rsplit(" ", 2)[1:] for f in figures] == [["602", "ms"], ["804", "ms"]]  # each member's own


# --------------------------------------------------------------------------- slots and devices that talk rarely


def test_time_slots_that_invert_the_priority_order_are_refused_in_one_line_naming_both(tmp_path: Path) -> None:
    """A id 120 priority 0 waits 240 ms, B id 3 priority 1 waits 206 ms: B would claim first."""
    a, b = raw_pair()
    for raw, own, prio, peer in ((a, 120, 0, 3), (b, 3, 1, 120)):
        raw["master"]["redundancy"] = {"node_id": own, "priority": prio, "peer_node_id": peer}
    (line,) = problems(a, b)
    assert line.startswith("A.yaml, B.yaml: master.redundancy: the CiA 302-2 time slots do not follow")
    assert "A.yaml (priority 0, node_id 120) waits 240 ms, B.yaml (priority 1, node_id 3) 206 ms" in line
    assert line.endswith("or a priority_slot_ms over 234 ms")  # 240 - 3 x 2: the fix it names holds
    for raw in (a, b):
        raw["master"]["redundancy"]["priority_slot_ms"] = 235
    assert problems(a, b) == []  # 240 < 235 + 6
    for raw in (a, b):
        del raw["master"]["redundancy"]["priority_slot_ms"]
    fa, fb = tmp_path / "A.yaml", tmp_path / "B.yaml"
    fa.write_text(yaml.safe_dump(a))
    fb.write_text(yaml.safe_dump(b))
    bad = _run_check(fa, fb)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
    assert str(fa) in bad.stderr and str(fb) in bad.stderr
    b["master"]["redundancy"]["node_id"], a["master"]["redundancy"]["peer_node_id"] = 121, 121
    assert problems(a, b) == []  # 240 < 200 + 242


def test_the_worst_takeover_counts_how_rarely_the_devices_talk() -> None:
    """1 s heartbeats: the standby hears a device at most 1 s after the master's next two
    heartbeats were due: 200 + 1000 ms, B's slot 404 ms, one heartbeat: 1,704 ms."""
    from canopen_gateway.checks.pair import takeover_worst_ms

    _, b = raw_pair()
    cfg = parse_config(b, "B.yaml", {})
    assert takeover_worst_ms(cfg) == 804  # the devices taken to talk every heartbeat
    for n in b["nodes"]:
        n.update(supervision="heartbeat", heartbeat_ms=1000)
    cfg = parse_config(b, "B.yaml", {})
    assert takeover_worst_ms(cfg, resolved(cfg)) == 1704
    for n in b["nodes"]:
        n.update(supervision="guarding", guard_time_ms=500, life_time_factor=4)
    ((key, text),) = [w for w in warnings(b, "B.yaml") if "talks unasked" in w[1]]
    assert key == "nodes" and "cannot tell the active gateway's death from its own cut cable" in text
