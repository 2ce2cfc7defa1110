"""``canopen-gateway dcf``: a node's CiA 306 DCF as the gateway configures it. Each file loads
in python canopen (``canopen.import_od``) with ``[DeviceComissioning]`` NodeID and Baudrate
(kbit/s) and the ParameterValue of every object the boot configuration writes, equal to the
boot tables of docs/canopen.md for the demo's nodes and to the boot steps of EDS-only nodes
made of third-party files (../shared/eds-corpus, read where they are)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import canopen
import pytest
import yaml

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.cli import main
from canopen_gateway.device.dcf import final_values
from tests.helpers import load_checked_config, with_nodes

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "config" / "demo.yaml"
CORPUS = ROOT / ".." / "shared" / "eds-corpus"


def boot_tables() -> dict[str, dict[ObjRef, int]]:
    """docs/canopen.md "What is configured at boot": per node, each object's last value."""
    text = (ROOT / "docs" / "canopen.md").read_text(encoding="utf-8")
    part = text.split("## What is configured at boot", 1)[1].split("\n## ", 1)[0]
    out: dict[str, dict[ObjRef, int]] = {}
    for block in part.split("\n### ")[1:]:
        heading = re.match(r"(\w+) \(.*, node id \d+, ", block)
        if heading is None:  # not a node's table (the DCF's own section)
            continue
        name = heading.group(1)
        values: dict[ObjRef, int] = {}
        for m in re.finditer(r"^\| (0x[0-9A-F]{4}:[0-9A-F]{2}) \| (-?\d+)", block, re.M):
            values[ObjRef.parse(m.group(1))] = int(m.group(2))
        out[name] = values
    return out


def value_of(od: canopen.ObjectDictionary, obj: ObjRef) -> Any:
    return od.get_variable(obj.index, obj.sub).value


def test_demo_nodes_dcfs_hold_the_boot_tables_of_the_docs(tmp_path: Path) -> None:
    tables = boot_tables()
    cfg = load_checked_config(DEMO)
    assert set(tables) == {n.name for n in cfg.nodes}
    assert main(["dcf", "-c", str(DEMO), "--all", "-o", str(tmp_path / "dcf")]) == 0
    for n in cfg.nodes:
        od = canopen.import_od(str(tmp_path / "dcf" / f"{n.name}.dcf"))
        assert (od.node_id, od.bitrate) == (n.node_id, 500_000), n.name
        assert tables[n.name], n.name
        for obj, value in tables[n.name].items():
            assert value_of(od, obj) == value, f"{n.name} {obj}"


def test_one_node_to_stdout_or_a_file_and_all_into_an_existing_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["dcf", "-c", str(DEMO), "--node", "wire"]) == 0
    out = capsys.readouterr().out
    assert "[DeviceComissioning]\nNodeID=1\nNodeName=wire\nBaudrate=500\n" in out
    assert main(["dcf", "-c", str(DEMO), "--node", "wire", "-o", str(tmp_path / "w.dcf")]) == 0
    assert (tmp_path / "w.dcf").read_text(encoding="utf-8") == out
    (tmp_path / "all").mkdir()
    assert main(["dcf", "-c", str(DEMO), "--all", "-o", str(tmp_path / "all")]) == 0
    assert sorted(p.name for p in (tmp_path / "all").iterdir()) == [
        "display.dcf", "magnet.dcf", "rotary.dcf", "rotary_sf.dcf", "wire.dcf"]  # fmt: skip
    capsys.readouterr()
    assert main(["dcf", "-c", str(DEMO), "--node", "nosuch"]) == 2
    assert "no such node; nodes: wire, magnet" in capsys.readouterr().err


def test_a_bus_without_can_bitrate_needs_bitrate_given(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    raw = yaml.safe_load(DEMO.read_text(encoding="utf-8"))
    del raw["can"]["bitrate"]
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    assert main(["dcf", "-c", str(path), "--node", "wire"]) == 2
    err = capsys.readouterr().err
    assert "can.bitrate" in err and "--bitrate" in err
    assert main(["dcf", "-c", str(path), "--node", "wire", "--bitrate", "250"]) == 0
    assert "\nBaudrate=250\n" in capsys.readouterr().out
    assert main(["dcf", "-c", str(path), "--node", "wire", "--bitrate", "300"]) == 2  # no CiA 301 rate
    assert "not a CiA 301 bit rate; kbit/s, one of: 10, 20, 50, 125, 250, 500, 800, 1000" in capsys.readouterr().err


def corpus_files() -> list[Path]:
    if not CORPUS.is_dir():
        pytest.skip(f"no {CORPUS} (third-party EDS files beside the checkout)")
    return sorted(CORPUS.glob("*.eds"))[:8] + sorted(CORPUS.glob("*.dcf"))


def test_eds_only_nodes_of_third_party_files_carry_their_boot_steps(tmp_path: Path) -> None:
    """A node made of a corpus EDS (or DCF) alone, with a heartbeat, a TPDO1 setting and an SDO write:
    the DCF holds the boot steps' last values, read back by python canopen."""
    done = []
    for eds in corpus_files():
        node = {"name": "dev", "node_id": 5, "eds": str(eds.resolve()), "heartbeat_ms": 250,
                "supervision": "heartbeat", "tpdo": {1: {"event_timer_ms": 50, "transmission": 254}},
                "sdo": [{"object": "0x1017:00", "value": 300}]}  # fmt: skip
        raw = {"can": {"interface": "virtual", "bitrate": 250000}, "nodes": [node]}
        cfg_path = tmp_path / f"{eds.stem}.yaml"
        cfg_path.write_text(yaml.safe_dump(raw), encoding="utf-8")
        try:
            canopen.import_od(str(eds))  # a file python canopen itself cannot read: not ours to test
            _, nodes = with_nodes(load_checked_config(cfg_path))
            steps = nodes["dev"].require().boot_steps
        except Exception:  # noqa: BLE001 - a file canopen or the gateway refuses, or without TPDO1
            continue
        out = tmp_path / f"{eds.stem}.dcf"
        assert main(["dcf", "-c", str(cfg_path), "--node", "dev", "-o", str(out)]) == 0
        od = canopen.import_od(str(out))
        assert (od.node_id, od.bitrate) == (5, 250_000)
        expected = {obj: step.value for obj, step in final_values(steps).items()}
        assert expected[ObjRef(0x1017, 0)] == 300
        assert ObjRef(0x1800, 0x05) in expected
        for obj, value in expected.items():
            assert value_of(od, obj) == value, f"{eds.name} {obj}"
        done.append(eds.name)
    assert len([d for d in done if d.endswith(".eds")]) >= 4, done
    assert len([d for d in done if d.endswith(".dcf")]) >= 2, done  # a DCF's commissioning replaced
    print("corpus files:", ", ".join(done))


def test_each_nodes_dcf_says_its_own_networks_bit_rate_number_and_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """config/two-networks.yaml: line1 at 500 kbit/s, line2 at 250; a node's DCF is of its
    network (python canopen reads its bit rate back); --bitrate is one bus's, so --all with
    several networks needs --network."""
    two = ROOT / "config" / "two-networks.yaml"
    assert main(["dcf", "-c", str(two), "--all", "-o", str(tmp_path / "all")]) == 0
    for name, bitrate, number, network in (("wire", 500, 1, "line1"), ("rotary", 250, 2, "line2")):
        text = (tmp_path / "all" / f"{name}.dcf").read_text(encoding="utf-8").replace("\r\n", "\n")
        assert f"\nBaudrate={bitrate}\nNetNumber={number}\nNetworkName={network}\n" in text, name
        assert canopen.import_od(str(tmp_path / "all" / f"{name}.dcf")).bitrate == bitrate * 1000
    capsys.readouterr()
    assert main(["dcf", "-c", str(two), "--all", "--bitrate", "125", "-o", str(tmp_path / "x")]) == 2
    assert "has 2 networks, each a bus of its own: give --network NAME with --bitrate" in capsys.readouterr().err
    assert main(["dcf", "-c", str(two), "--all", "--network", "line2", "--bitrate", "125", "-o", str(tmp_path / "l2")]) == 0
    assert sorted(p.name for p in (tmp_path / "l2").iterdir()) == ["magnet.dcf", "rotary.dcf"]
    assert "\nBaudrate=125\nNetNumber=2\n" in (tmp_path / "l2" / "magnet.dcf").read_text(encoding="utf-8").replace("\r\n", "\n")
    assert main(["dcf", "-c", str(two), "--node", "display"]) == 0  # one node: its network's
    assert "\nBaudrate=500\nNetNumber=1\nNetworkName=line1\n" in capsys.readouterr().out.replace("\r\n", "\n")  # the AP05 file: CRLF
