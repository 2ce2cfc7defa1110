"""Cross-process: simulated devices in one process (`canopen-gateway simulate`), the gateway in
another, sharing a CAN bus through python-can-remote (as the compose demo does)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from canopen_gateway.config import load_config
from tests.helpers import free_port, gateway_of, start_can_remote, wait_can_remote, wait_until

pytest.importorskip("can_remote")


async def test_gateway_serves_devices_simulated_in_another_process(tmp_path: Path) -> None:
    port = free_port()
    server = start_can_remote(port, f"xp{port}")
    raw = {
        "gateway": {"name": "xp"},
        "can": {"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"},
        "master": {"heartbeat_ms": 200},
        "nodes": [
            {"name": "wire", "node_id": 1, "profile": "sgh10"},
            {"name": "display", "node_id": 125, "profile": "ap05"},
        ],
        "modbus": {"port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
    }
    cfg_file = tmp_path / "xp.yaml"
    cfg_file.write_text(yaml.safe_dump(raw))
    sim = None
    gw = None
    try:
        wait_can_remote(server, port)
        sim = subprocess.Popen(
            [sys.executable, "-m", "canopen_gateway", "simulate", "-c", str(cfg_file)],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        assert "simulating" in (sim.stdout.readline() if sim.stdout else "")
        gw = gateway_of(load_config(cfg_file, environ={}), simulate=False)
        await gw.start()
        for name in ("wire", "display"):
            await wait_until(lambda n=name: gw.image.nodes[n].operational(), 10, f"{name} operational")
        seq = gw.image.nodes["wire"].signals["position"].seq
        await wait_until(lambda: gw.image.nodes["wire"].signals["position"].seq > seq + 3, 5, "positions flowing")
    finally:
        if gw is not None:
            await gw.stop()
        for p in (sim, server):
            if p is not None:
                p.terminate()
                try:
                    p.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    p.kill()
