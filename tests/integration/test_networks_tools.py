"""The plant's tools on a gateway of two CAN networks (two in-process virtual buses, the devices
simulated on each): ``sdo`` and ``nmt`` with ``--network`` reach the running gateway's devices
through its one command socket; ``fault --network`` finds the gateway's web port through that
socket and lists the network's simulated nodes; the console records one network's bus
(``/api/monitor/record?network=``), which ``decode --network`` reads back; ``monitor --record
--network`` records a network's bus of its own when no gateway runs."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
import yaml

from canopen_gateway.app import Gateway
from canopen_gateway.checks import load_checked
from canopen_gateway.cli import main
from tests.helpers import free_port, unique_channel, wait_until
from tests.integration.test_web_http import http


def two_networks(path: Path, health_port: int) -> Path:
    """wire (SGH10, id 1) on line1, rotary (POSI+, id 5) on line2, every device simulated."""
    def net(name: str, node: dict[str, Any]) -> dict[str, Any]:
        return {"name": name, "can": {"interface": "virtual", "channel": unique_channel(), "bitrate": 500000},
                "master": {"heartbeat_ms": 200, "heartbeat_timeout_multiple": 3}, "nodes": [node]}  # fmt: skip

    raw = {
        "gateway": {"name": "two"},
        "networks": [net("line1", {"name": "wire", "node_id": 1, "profile": "sgh10"}),
                     net("line2", {"name": "rotary", "node_id": 5, "profile": "posi_plus"})],
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "health": {"port": health_port},
        "command_socket": {"path": "cmd.sock"},
        "simulate": {"nodes": "all"},
    }  # fmt: skip
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


async def cli(*args: str) -> int:
    return int(await asyncio.to_thread(main, list(args)))


async def test_the_tools_reach_each_network_of_a_running_gateway_through_its_command_socket(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the file names a port nothing listens on; the gateway's own shell moved it
    f = two_networks(tmp_path / "two.yaml", free_port())
    port = free_port()
    gw = Gateway(*load_checked(f, environ={"CANOPEN_GATEWAY__HEALTH__PORT": str(port)}))
    await gw.start()
    try:
        for name in ("wire", "rotary"):
            await wait_until(lambda name=name: gw.image.nodes[name].usable(), 10, f"{name} operational")
        assert gw.command_socket.path == tmp_path / "cmd.sock"
        capsys.readouterr()

        assert await cli("sdo", "read", "-c", str(f), "--network", "line2", "rotary", "0x1018:01") == 0
        out = capsys.readouterr()
        assert "through the running gateway at its command socket" in out.err and out.out.strip()
        assert await cli("nmt", "-c", str(f), "--network", "line2", "stop", "all") == 0
        assert "through the running gateway at its command socket" in capsys.readouterr().out
        await wait_until(lambda: gw.image.nodes["rotary"].health.nmt_state.name == "STOPPED", 5, "rotary stopped")
        assert gw.image.nodes["wire"].operational()  # line1's node: not addressed

        assert await cli("fault", "-c", str(f), "--network", "line2") == 0  # the port: from the socket
        listed = capsys.readouterr().out.splitlines()
        assert [line.split(":")[0] for line in listed if line.startswith(("wire:", "rotary:"))] == ["rotary"]

        base = f"http://127.0.0.1:{port}/api/monitor/record"
        code, _, body = await http(f"{base}?network=line3&seconds=1")
        assert code == 400 and b"no network named 'line3'; networks: line1, line2" in body
        code, headers, body = await http(f"{base}?network=line2&seconds=1&format=asc")
        assert code == 200 and "two-line2-bus-" in headers["Content-Disposition"]
    finally:
        await gw.stop()
    trace = tmp_path / "line2.asc"
    trace.write_bytes(body)
    capsys.readouterr()
    assert main(["decode", "-c", str(f), "--network", "line2", str(trace)]) == 0
    decoded = capsys.readouterr().out
    assert "rotary" in decoded and "wire" not in decoded  # line2's bus: node 5 only


def test_monitor_records_the_bus_of_the_network_it_is_given(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No gateway runs: the monitor simulates the network's own devices on its own bus."""
    f = two_networks(tmp_path / "two.yaml", free_port())
    trace = tmp_path / "bus.log"
    # the simulated POSI+'s boot-up (it sends no heartbeat until a master sets 1017h)
    argv = ["monitor", "-c", str(f), "--network", "line2", "--kind", "heartbeat", "--count", "1", "--duration", "10"]
    assert main([*argv, "--record", str(trace)]) == 0
    out = capsys.readouterr()
    assert "acting on this command's own simulated devices (rotary)" in out.err
    assert "recorded" in out.err and "rotary" in out.out and "boot-up" in out.out
    assert main(["decode", "-c", str(f), "--network", "line2", str(trace)]) == 0
    decoded = capsys.readouterr().out
    assert "rotary" in decoded and "heartbeat" in decoded and "wire" not in decoded
