"""LSS Fast Scan on a bus: ``canopen-gateway lss fast-scan`` gives node ids to identical
simulated SGH10s shipped unconfigured, serial numbers unknown (the lowest LSS address first),
and python canopen's own master (``LssMaster.fast_scan``) finds the same device on our
simulator's LSS slave: the exchange is CiA 305's, not only ours."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import canopen
import pytest
import yaml

from canopen_gateway.cli import main
from tests.helpers import load_checked_config, unique_channel, with_nodes

SGH10 = (0x195, 0xFFFFFFFF, 0xFFFFFFFF)  # SGH10 manual 4.6: vendor, product, revision
SERIALS = {"enc_a": 0x2300, "enc_b": 0x0F01}


def config(tmp_path: Path) -> Path:
    options = {name: {"features": {"lss_slave": {"unconfigured": True, "serial_number": serial}}}
               for name, serial in SERIALS.items()}  # fmt: skip
    cfg: dict[str, Any] = {
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 0},
        "nodes": [{"name": name, "node_id": i, "profile": "sgh10", "configure": False}
                  for i, name in enumerate(SERIALS, start=1)],  # fmt: skip
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": "all", "options": options},
    }
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return path


def test_fast_scan_gives_identical_unconfigured_devices_node_ids_lowest_address_first(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    path = config(tmp_path)
    known = ["vendor=0x195", "product=0xFFFFFFFF", "revision=0xFFFFFFFF"]
    assert main(["lss", "-c", str(path), "fast-scan", "10", "count=2", "store", *known, "wait=0.05"]) == 0
    out = capsys.readouterr().out.splitlines()
    found = [line for line in out if line.startswith("found ")]
    assert [f.split()[1] for f in found] == ["0x195:0xFFFFFFFF:0xFFFFFFFF:0xF01", "0x195:0xFFFFFFFF:0xFFFFFFFF:0x2300"]
    assert "  node id 10 configured, stored" in out and "  node id 11 configured, stored" in out


def test_fast_scan_without_unconfigured_devices_fails_in_words(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    raw = yaml.safe_load(config(tmp_path).read_text(encoding="utf-8"))
    raw["simulate"]["options"] = {}  # devices with their node ids take no part
    path = tmp_path / "configured.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    assert main(["lss", "-c", str(path), "fast-scan", "wait=0.02"]) == 1
    assert "no unconfigured LSS slave answered" in capsys.readouterr().err


def test_python_canopens_master_finds_the_unconfigured_device_on_our_simulator(tmp_path: Path) -> None:
    from canopen_gateway.sim.buses import SimulatedBus

    raw = yaml.safe_load(config(tmp_path).read_text(encoding="utf-8"))
    del raw["simulate"]["options"]["enc_b"]  # one unconfigured device: python canopen's master
    path = tmp_path / "one.yaml"  # takes the first answer of a step, another slave's comes later
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    cfg, nodes = with_nodes(load_checked_config(path))
    sim = SimulatedBus(cfg, nodes)
    sim.start()
    network = canopen.Network()
    network.connect(interface="virtual", channel=cfg.can.channel)
    try:
        network.lss.RESPONSE_TIMEOUT = 0.03  # each step without an answer waits this long
        ok, address = network.lss.fast_scan()
        assert ok and tuple(address) == (*SGH10, SERIALS["enc_a"])
        # the device found is in LSS configuration: it answers an inquiry
        assert network.lss.inquire_lss_address(0x5D) == SERIALS["enc_a"]
    finally:
        network.disconnect()
        sim.stop()
