"""Demo fault injection: a simulated device unplugged, an EMCY raised, a reboot, from the web
API (``/api/sim``) and the command line (``canopen-gateway fault``); the gateway reports each
as it would a real one (lost and stale, EMCY counted), and only simulated devices are touched."""

from __future__ import annotations

import asyncio
import json
import time
import urllib.error
import urllib.request
from typing import Any

import pytest

from gateway.app import Gateway
from gateway.cli import main
from gateway.image import Quality
from tests.helpers import free_port, make_config, node_operational, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}


async def call(url: str, method: str = "GET") -> tuple[int, dict[str, Any]]:
    def go() -> tuple[int, dict[str, Any]]:
        try:
            with urllib.request.urlopen(urllib.request.Request(url, method=method), timeout=5) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as e:
            return e.code, json.loads(e.read())

    return await asyncio.to_thread(go)


async def test_faults_from_the_web_api_show_as_the_gateway_reports_real_ones() -> None:
    cfg = make_config([WIRE, DISPLAY], health={"port": free_port()}, simulate={"nodes": ["wire"]})
    gw = Gateway(cfg)
    await gw.start()
    base = f"http://127.0.0.1:{gw.health.port}/api/sim"
    try:
        await wait_until(lambda: node_operational(gw, "wire"), what="wire operational")
        code, doc = await call(base)
        assert code == 200 and doc["nodes"] == ["wire"]
        assert set(doc["faults"]) == {"unplug", "plug", "emcy", "clear-emcy", "reboot"}

        code, doc = await call(f"{base}/wire/unplug", "POST")
        assert (code, doc["result"]) == (200, "unplugged")
        node = gw.image.nodes["wire"]
        await wait_until(lambda: not node.health.alive, what="wire lost")
        # the last value is kept but no longer good: stale (Modbus 0x0B, Zenoh "stale")
        assert node.quality(node.signals["position"], time.monotonic()) == Quality.STALE
        code, doc = await call(f"{base}/wire/plug", "POST")
        assert code == 200
        await wait_until(lambda: node_operational(gw, "wire"), what="wire back")

        before = node.health.emcy_count
        code, doc = await call(f"{base}/wire/emcy", "POST")
        assert code == 200 and "EMCY" in doc["result"]
        await wait_until(lambda: node.health.emcy_count > before, what="the EMCY")

        # only simulated devices: the display is real (not simulated here), faults unknown 404
        code, doc = await call(f"{base}/display/unplug", "POST")
        assert code == 404 and doc["message"].startswith("no simulated node named 'display'")
        code, doc = await call(f"{base}/wire/explode", "POST")
        assert code == 404 and "faults: unplug, plug, emcy, clear-emcy, reboot" in doc["message"]
    finally:
        await gw.stop()


async def test_fault_from_the_command_line_reaches_the_running_gateway(
    tmp_path: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    import yaml

    port = free_port()
    cfg = make_config([WIRE], health={"port": port})
    gw = Gateway(cfg)
    await gw.start()
    path = tmp_path / "demo.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "can": {"interface": "virtual", "channel": cfg.can.channel},
                "nodes": [WIRE],
                "health": {"port": port},
            }
        ),  # fmt: skip
        encoding="utf-8",
    )
    try:
        await wait_until(lambda: node_operational(gw, "wire"), what="wire operational")
        assert await asyncio.to_thread(main, ["fault", "-c", str(path), "wire", "reboot"]) == 0
        assert capsys.readouterr().out.strip() == "wire: rebooted (boot-up sent)"
        await wait_until(lambda: gw.image.nodes["wire"].health.boot_count >= 1, what="the boot-up")
        code = await asyncio.to_thread(main, ["fault", "-c", str(path), "nosuch", "unplug"])
        assert code == 2
        assert "no simulated node named 'nosuch'" in capsys.readouterr().err
    finally:
        await gw.stop()
