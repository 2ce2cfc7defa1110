"""Screenshots of the web console for docs/web.md, taken with headless Chromium.

    python -m tests.browser.screenshot config/demo.yaml docs/images

runs the gateway of the config in this process (its simulated nodes included; the Modbus,
Zenoh and health ports of the config, or free ones when a running demo holds them;
commissioning switched on with a throw-away token), waits until every node is operational and the page
shows it live, and writes ``web-overview.png``, ``web-node.png``, ``web-commissioning.png``, ``web-trends.png``
``web-events.png`` and ``web-monitor.png``.
"""

from __future__ import annotations

import asyncio
import socket
import sys
from pathlib import Path
from typing import Any

from canopen_gateway.config import load_config
from tests.browser.chromium import chromium
from tests.helpers import free_port, gateway_of, node_operational, wait_until

TOKEN = "screenshot-token-only"


def _shoot(base: str, out: Path, node: str) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    def fit(driver: Any) -> None:
        height = driver.execute_script("return document.documentElement.scrollHeight")
        driver.set_window_size(1400, min(int(height) + 120, 2400))

    with chromium(1400, 1000) as d:
        d.get(base + "/")
        WebDriverWait(d, 15).until(lambda d: d.find_element(By.ID, "conn").text == "live")
        WebDriverWait(d, 15).until(
            lambda d: d.find_element(By.ID, "ov-bus").text.count("/s") >= 2
            and "0 /s" not in d.find_element(By.ID, "ov-bus").text
        )
        fit(d)
        d.save_screenshot(str(out / "web-overview.png"))
        d.set_window_size(1400, 1000)
        d.get(f"{base}/node/{node}")
        WebDriverWait(d, 15).until(lambda d: d.find_element(By.ID, "conn").text == "live")
        d.set_window_size(1400, 1300)
        d.save_screenshot(str(out / "web-node.png"))
        d.set_window_size(1400, 1000)
        d.get(base + "/commissioning")
        WebDriverWait(d, 15).until(lambda d: d.find_elements(By.CSS_SELECTOR, "#sr-node option"))
        d.find_element(By.ID, "token").send_keys(TOKEN)
        d.find_element(By.CSS_SELECTOR, "#form-login button[type=submit]").click()
        WebDriverWait(d, 15).until(lambda d: d.find_element(By.ID, "ops").is_displayed())
        d.find_element(By.ID, "sr-object").send_keys("0x1018:09")
        d.find_element(By.CSS_SELECTOR, "#form-sdo-read button").click()
        WebDriverWait(d, 15).until(lambda d: "abort" in d.find_element(By.ID, "result-sdo-read").text)
        fit(d)
        d.save_screenshot(str(out / "web-commissioning.png"))


def _shoot_first_hour(base: str, out: Path, node: str = "wire") -> None:
    """``web-trends.png``: the node page's trends, good for a while, then stale after the page's
    fault button unplugged the simulated node; ``web-events.png``: the event log after it."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    with chromium(1280, 1000) as d:
        d.get(f"{base}/node/{node}")
        WebDriverWait(d, 30).until(
            lambda d: d.execute_script("return trendCharts.position ? trendCharts.position.t.length : 0") >= 30
        )
        d.find_element(By.CSS_SELECTOR, '#fault-buttons button[data-fault="unplug"]').click()
        WebDriverWait(d, 30).until(
            lambda d: d.execute_script(
                "const c = trendCharts.position; return c.stale.filter(v => v !== null).length"
            ) >= 12
        )
        d.execute_script("document.getElementById('h-faults').scrollIntoView()")
        d.save_screenshot(str(out / "web-trends.png"))
        d.find_element(By.CSS_SELECTOR, '#fault-buttons button[data-fault="plug"]').click()
        d.get(base + "/events")
        WebDriverWait(d, 30).until(lambda d: d.find_elements(By.CSS_SELECTOR, "#events tbody tr[data-kind]"))
        WebDriverWait(d, 30).until(lambda d: "lost -> alive" in d.find_element(By.ID, "events").text)
        d.save_screenshot(str(out / "web-events.png"))


def _shoot_monitor(base: str, out: Path) -> None:
    """``web-monitor.png``: the bus monitor of the demo, paused once it has a screenful."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    with chromium(1280, 1000) as d:
        d.get(base + "/monitor")
        WebDriverWait(d, 30).until(
            lambda d: len(d.find_elements(By.CSS_SELECTOR, "#frames tbody tr[data-kind]")) >= 60
        )
        d.find_element(By.ID, "mon-pause").click()
        d.save_screenshot(str(out / "web-monitor.png"))


def _port_or_free(port: int) -> int:
    """``port`` when nothing listens on it (the picture then shows the config's ports)."""
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return free_port()
    return port


async def main(config: str, out_dir: str, node: str = "display") -> None:
    cfg = load_config(config, environ={})
    zenoh_port = _port_or_free(int(cfg.zenoh.listen[0].rsplit(":", 1)[1]))
    environ = {
        "CANOPEN_GATEWAY__MODBUS__PORT": str(_port_or_free(cfg.modbus.port)),
        "CANOPEN_GATEWAY__ZENOH__LISTEN": f"['tcp/127.0.0.1:{zenoh_port}']",
        "CANOPEN_GATEWAY__HEALTH__PORT": str(_port_or_free(cfg.health.port)),
        "CANOPEN_GATEWAY__WEB__WRITES": "true",
        "CANOPEN_GATEWAY__WEB__TOKEN": TOKEN,
    }
    cfg = load_config(config, environ=environ)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    gw = gateway_of(cfg)
    await gw.start()
    try:
        for n in cfg.nodes:
            await wait_until(lambda n=n: node_operational(gw, n.name), 15, f"{n.name} operational")
        await asyncio.to_thread(_shoot, f"http://127.0.0.1:{gw.health.port}", out, node)
        await asyncio.to_thread(_shoot_first_hour, f"http://127.0.0.1:{gw.health.port}", out)
        await asyncio.to_thread(_shoot_monitor, f"http://127.0.0.1:{gw.health.port}", out)
    finally:
        await gw.stop()


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:]))
