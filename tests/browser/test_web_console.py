"""The web console in a real browser (headless Debian Chromium via selenium) against a running
gateway with simulated devices: the page loads, the nodes table follows a node lost and back,
live values move, write controls exist only with ``web.writes`` and work with the token, and
basic accessibility holds (every control labelled, text contrast at least 4.5:1).

Selenium blocks, so its calls run in a worker thread while the gateway runs on the test's event
loop; every wait is a WebDriverWait on page content."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager
from typing import Any

import pytest

from canopen_gateway.app import Gateway
from tests.browser.chromium import BrowserUnavailable, chromium
from tests.helpers import free_port, gateway_of, make_config, node_operational, wait_until

TOKEN = "browser-test-token-7"
WAIT_S = 15.0

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    try:
        with chromium() as driver:
            yield driver
    except BrowserUnavailable as exc:
        pytest.skip(f"browser tests need a working headless Chromium: {exc}")


@asynccontextmanager
async def gateway(writes: bool = False, unconfigured: bool = False) -> AsyncIterator[tuple[Gateway, str]]:
    """``unconfigured``: the simulated wire also takes part in LSS Fast Scan (serial 0x2300)."""
    lss = {"wire": {"features": {"lss_slave": {"unconfigured": True, "serial_number": 0x2300}}}}
    cfg = make_config(
        [
            {"name": "wire", "node_id": 1, "profile": "sgh10"},
            {"name": "display", "node_id": 125, "profile": "ap05"},
        ],
        health={"port": free_port()},
        web={"writes": True, "token": TOKEN} if writes else {},
        simulate={"options": lss if unconfigured else {}},
    )
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        await wait_until(lambda: node_operational(gw, "display"), 5, "display operational")
        yield gw, f"http://127.0.0.1:{gw.health.port}"
    finally:
        await gw.stop()


async def run(fn: Callable[..., Any], *args: Any) -> Any:
    """A blocking selenium step in a worker thread (the gateway keeps running)."""
    return await asyncio.to_thread(fn, *args)


def wait_for(driver: Any, cond: Callable[[Any], Any], what: str) -> Any:
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(driver, WAIT_S).until(cond, message=f"waiting for {what}")


def cell(driver: Any, node: str, col: str) -> str:
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
    from selenium.webdriver.common.by import By

    try:
        return driver.find_element(
            By.CSS_SELECTOR, f'#nodes tr[data-node="{node}"] td[data-col="{col}"]'
        ).text
    except (NoSuchElementException, StaleElementReferenceException):
        return ""


def value_cell(driver: Any, signal: str, col: str = "value") -> str:
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
    from selenium.webdriver.common.by import By

    try:
        return driver.find_element(
            By.CSS_SELECTOR, f'#signals tr[data-signal="{signal}"] td[data-col="{col}"]'
        ).text
    except (NoSuchElementException, StaleElementReferenceException):
        return ""


async def test_the_page_loads_with_the_overview_and_every_node(browser: Any) -> None:
    async with gateway() as (_, base):

        def check() -> None:
            browser.get(base + "/")
            assert browser.title == "canopen-gateway: overview"
            wait_for(browser, lambda d: cell(d, "wire", "quality") == "good", "wire good")
            wait_for(browser, lambda d: cell(d, "display", "link") == "ok", "display link ok")
            from selenium.webdriver.common.by import By

            bus = browser.find_element(By.ID, "ov-bus").text
            assert "virtual" in bus and "ok" in bus
            assert cell(browser, "wire", "nmt_state") == "operational"
            assert cell(browser, "wire", "supervision") == "heartbeat 100 ms, lost after 300 ms"
            assert not browser.find_element(By.ID, "ov-pair-card").is_displayed()  # no pair
            wait_for(browser, lambda d: d.find_element(By.ID, "conn").text == "live", "live")
            # a node page of no node: a page that says so and links the nodes there are
            browser.get(base + "/node/nosuch")
            assert browser.title == "canopen-gateway: not found"
            wait_for(browser, lambda d: "nosuch" in d.find_element(By.ID, "nf-what").text, "what")
            assert browser.find_element(By.ID, "nf-what").text == "No node named “nosuch” is configured on this gateway."  # fmt: skip
            links = [a.text for a in browser.find_elements(By.CSS_SELECTOR, "#nf-nodes a")]
            assert links == ["wire", "display"]

        await run(check)


async def test_the_overview_shows_the_role_of_a_gateway_of_a_pair_and_its_peer(
    browser: Any,
) -> None:
    """A gateway of a hot-standby pair alone on its bus: it negotiates, becomes active, and
    hears nothing of the other one."""
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        master={"redundancy": {"node_id": 101, "priority": 0, "peer_node_id": 102}},
        health={"port": free_port()},
    )
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: gw.master.role == "active", 10, "active")
        from selenium.webdriver.common.by import By

        def pair_text(d: Any) -> str:
            return str(d.find_element(By.ID, "ov-pair").text)

        def check() -> None:
            browser.get(f"http://127.0.0.1:{gw.health.port}/")
            wait_for(browser, lambda d: "active" in pair_text(d), "the pair block")
            assert browser.find_element(By.ID, "ov-pair-card").is_displayed()
            text = pair_text(browser)
            assert "This gateway\nactive" in text, text
            assert "not heard node id 102" in text, text
            assert "Its heartbeat\nnever heard" in text, text
            assert "Master id\n101" in text, text  # the master heard active: itself

        await run(check)
    finally:
        await gw.stop()


async def test_the_nodes_table_shows_a_node_going_lost_and_back(browser: Any) -> None:
    async with gateway() as (gw, base):
        await run(browser.get, base + "/")
        await run(wait_for, browser, lambda d: cell(d, "wire", "presence") == "alive", "alive")
        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.silence())
        await run(wait_for, browser, lambda d: cell(d, "wire", "presence") == "lost", "lost")
        # presence and quality may come in two updates of the row: wait for both
        await run(wait_for, browser, lambda d: cell(d, "wire", "quality") == "stale", "stale")
        assert await run(cell, browser, "wire", "losses") == "1"
        assert await run(cell, browser, "display", "presence") == "alive"  # only wire
        gw.sim.runner.call(lambda now: sim.unsilence(now))
        await run(wait_for, browser, lambda d: cell(d, "wire", "presence") == "alive", "back")
        await run(wait_for, browser, lambda d: cell(d, "wire", "quality") == "good", "good")
        assert await run(cell, browser, "wire", "losses") == "1"


async def test_a_live_value_changes_on_the_node_page(browser: Any) -> None:
    async with gateway() as (_, base):
        await run(browser.get, base + "/node/wire")
        first = await run(
            wait_for, browser, lambda d: value_cell(d, "position") or None, "a position value"
        )
        assert await run(value_cell, browser, "position", "quality") == "good"
        assert await run(value_cell, browser, "position", "unit") == "mm"
        assert await run(value_cell, browser, "position", "modbus") == "IR 100-101 @ unit 1"
        assert (
            await run(value_cell, browser, "position", "zenoh")
            == "canopen/test/wire/value/position"
        )
        await run(
            wait_for, browser, lambda d: value_cell(d, "position") not in ("", first), "a new value"
        )


async def test_write_controls_are_absent_when_writes_are_off(browser: Any) -> None:
    async with gateway(writes=False) as (_, base):
        from selenium.webdriver.common.by import By

        def check() -> None:
            browser.get(base + "/")
            wait_for(browser, lambda d: cell(d, "wire", "quality") == "good", "table")
            assert browser.find_elements(By.ID, "nav-commission") == []
            assert browser.find_elements(By.CSS_SELECTOR, "input, select, textarea, form") == []
            browser.get(base + "/commissioning")
            assert "not found" in browser.find_element(By.TAG_NAME, "body").text
            assert browser.find_elements(By.CSS_SELECTOR, "input, form") == []

        await run(check)


async def test_commissioning_needs_the_token_and_an_sdo_write_reaches_the_device(
    browser: Any,
) -> None:
    async with gateway(writes=True) as (gw, base):
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import Select

        def unlock(token: str) -> None:
            box = browser.find_element(By.ID, "token")
            box.clear()
            box.send_keys(token)
            browser.find_element(By.CSS_SELECTOR, "#form-login button[type=submit]").click()

        def text(id_: str) -> str:
            return browser.find_element(By.ID, id_).text

        def check() -> None:
            browser.get(base + "/")
            wait_for(browser, lambda d: d.find_elements(By.ID, "nav-commission"), "nav link")
            browser.get(base + "/commissioning")
            wait_for(
                browser, lambda d: d.find_elements(By.CSS_SELECTOR, "#sw-node option"), "nodes"
            )
            assert not browser.find_element(By.ID, "ops").is_displayed()
            unlock("not-the-token")
            wait_for(browser, lambda d: text("result-login") == "Wrong token.", "refusal")
            assert not browser.find_element(By.ID, "ops").is_displayed()
            unlock(TOKEN)
            wait_for(browser, lambda d: d.find_element(By.ID, "ops").is_displayed(), "unlocked")
            Select(browser.find_element(By.ID, "sw-node")).select_by_value("wire")
            browser.find_element(By.ID, "sw-object").send_keys("0x6401:01")
            browser.find_element(By.ID, "sw-value").send_keys("4321")
            browser.find_element(By.CSS_SELECTOR, "#form-sdo-write button").click()
            wait_for(browser, lambda d: text("result-sdo-write").startswith("done"), "write done")
            Select(browser.find_element(By.ID, "sr-node")).select_by_value("wire")
            browser.find_element(By.ID, "sr-object").send_keys("0x1018:09")
            browser.find_element(By.CSS_SELECTOR, "#form-sdo-read button").click()
            wait_for(
                browser, lambda d: "Sub-index does not exist" in text("result-sdo-read"), "abort"
            )
            assert "0x06090011" in text("result-sdo-read")

        await run(check)
        assert gw.sim.nodes["wire"].get(0x6401, 1) == 4321


#: Every input, select and textarea has a label (a <label for>, a wrapping label or aria-label).
UNLABELLED_JS = """
return [...document.querySelectorAll('input, select, textarea')]
  .filter(e => e.type !== 'hidden' && !(e.labels && e.labels.length)
          && !e.getAttribute('aria-label') && !e.getAttribute('aria-labelledby'))
  .map(e => e.id || e.name || e.outerHTML.slice(0, 60));
"""

#: WCAG 2.1 contrast ratio (relative luminance, 1.4.3) of every visible element with text of its
#: own, its colour against the background it is painted on (ancestors' backgrounds composed).
LOW_CONTRAST_JS = """
function parse(s) {
  const m = s.match(/rgba?\\(([^)]+)\\)/);
  if (!m) return null;
  const p = m[1].split(/[ ,\\/]+/).filter(Boolean).map(parseFloat);
  return { rgb: p.slice(0, 3), a: p.length > 3 ? p[3] : 1 };
}
function lum(rgb) {
  const [r, g, b] = rgb.map(v => { v /= 255; return v <= 0.03928 ? v / 12.92 : Math.pow((v + 0.055) / 1.055, 2.4); });
  return 0.2126 * r + 0.7152 * g + 0.0722 * b;
}
function background(el) {
  const layers = [];
  for (let e = el; e; e = e.parentElement) {
    const c = parse(getComputedStyle(e).backgroundColor);
    if (c && c.a > 0) { layers.push(c); if (c.a >= 1) break; }
  }
  let rgb = [255, 255, 255];
  for (const l of layers.reverse()) rgb = rgb.map((v, i) => l.rgb[i] * l.a + v * (1 - l.a));
  return rgb;
}
const out = [];
let checked = 0;
for (const el of document.querySelectorAll('body *')) {
  if (![...el.childNodes].some(n => n.nodeType === 3 && n.textContent.trim())) continue;
  const st = getComputedStyle(el), r = el.getBoundingClientRect();
  if (!r.width || !r.height || st.visibility === 'hidden' || el.closest('[hidden]')) continue;
  const bg = background(el), fg = parse(st.color);
  const fgRgb = fg.rgb.map((v, i) => v * fg.a + bg[i] * (1 - fg.a));
  const a = lum(fgRgb), b = lum(bg);
  const ratio = (Math.max(a, b) + 0.05) / (Math.min(a, b) + 0.05);
  checked++;
  if (ratio < 4.5) out.push(el.tagName + ' "' + el.textContent.trim().slice(0, 40) + '" ' + ratio.toFixed(2));
}
return [checked, out];
"""


async def test_labels_and_text_contrast_pass_basic_accessibility_checks(browser: Any) -> None:
    async with gateway(writes=True) as (gw, base):
        from selenium.webdriver.common.by import By

        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.silence())  # lost, stale: the red and amber badges
        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].raise_emcy(0xFF00, 0x81, now=now))

        def audit(path: str, ready: Callable[[Any], Any], what: str) -> list[str]:
            browser.get(base + path)
            wait_for(browser, ready, what)
            problems = [f"{path}: unlabelled {x}" for x in browser.execute_script(UNLABELLED_JS)]
            checked, low = browser.execute_script(LOW_CONTRAST_JS)
            assert checked > 20, f"{path}: only {checked} text elements checked"
            return problems + [f"{path}: contrast {x}" for x in low]

        def check() -> list[str]:
            problems = audit("/", lambda d: cell(d, "wire", "presence") == "lost", "wire lost")
            problems += audit(
                "/node/display",
                lambda d: d.find_elements(By.CSS_SELECTOR, "#node-errors .badge.bad"),
                "active error",
            )
            browser.get(base + "/commissioning")
            wait_for(browser, lambda d: d.find_elements(By.CSS_SELECTOR, "#sw-node option"), "form")
            browser.find_element(By.ID, "token").send_keys("wrong-token-here")
            browser.find_element(By.CSS_SELECTOR, "#form-login button[type=submit]").click()
            wait_for(browser, lambda d: d.find_element(By.ID, "result-login").text, "refusal")
            problems += [
                f"/commissioning: unlabelled {x}" for x in browser.execute_script(UNLABELLED_JS)
            ]
            browser.find_element(By.ID, "token").clear()
            browser.find_element(By.ID, "token").send_keys(TOKEN)
            browser.find_element(By.CSS_SELECTOR, "#form-login button[type=submit]").click()
            wait_for(browser, lambda d: d.find_element(By.ID, "ops").is_displayed(), "unlocked")
            checked, low = browser.execute_script(LOW_CONTRAST_JS)
            problems += [f"/commissioning: contrast {x}" for x in low]
            return problems

        assert await run(check) == []


async def test_the_signals_table_fits_a_1280_px_window(browser: Any) -> None:
    """Every column of the node page's signals table, Modbus and Zenoh included, is visible at
    1280 px without scrolling sideways (the AP05 has the longest names and keys)."""
    async with gateway() as (_, base):

        def check() -> None:
            from selenium.webdriver.common.by import By

            browser.set_window_size(1280, 1000)
            try:
                browser.get(base + "/node/display")
                wait_for(browser, lambda d: value_cell(d, "status_word") or None, "a value")
                wrap = browser.find_element(By.CSS_SELECTOR, "#signals").find_element(
                    By.XPATH, ".."
                )
                scroll, client = browser.execute_script(
                    "return [arguments[0].scrollWidth, arguments[0].clientWidth]", wrap
                )
                assert scroll <= client, f"signals table {scroll} px wide in {client} px"
            finally:
                browser.set_window_size(1400, 1000)

        await run(check)


async def test_the_overview_shows_another_master_on_the_bus(browser: Any) -> None:
    import can

    async with gateway() as (gw, base):
        await run(browser.get, base + "/")
        other = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            other.send(can.Message(arbitration_id=0x000, data=[0x80, 0], is_extended_id=False))
        finally:
            other.shutdown()

        def shown(d: Any) -> bool:
            from selenium.webdriver.common.by import By

            return "NMT preop to every node (id 0)" in d.find_element(By.ID, "ov-bus").text

        await run(wait_for, browser, shown, "the other master on the overview")


async def test_the_commissioning_page_scans_the_bus_and_fast_scans_an_unconfigured_device(browser: Any) -> None:
    async with gateway(writes=True, unconfigured=True) as (_, base):
        from selenium.webdriver.common.by import By

        def check() -> None:
            browser.get(base + "/commissioning")
            box = wait_for(browser, lambda d: d.find_element(By.ID, "token"), "the token box")
            box.clear()
            box.send_keys(TOKEN)
            browser.find_element(By.CSS_SELECTOR, "#form-login button[type=submit]").click()
            wait_for(browser, lambda d: d.find_element(By.ID, "ops").is_displayed(), "unlocked")
            browser.find_element(By.CSS_SELECTOR, "#form-scan button").click()
            result = wait_for(
                browser,
                lambda d: (
                    "config node wire" in d.find_element(By.ID, "result-scan").text
                    and d.find_element(By.ID, "result-scan").text
                ),
                "the scan",
            )
            assert "profile sgh10; config node wire (sgh10)" in result
            assert "profile ap05; config node display (ap05)" in result
            for field, value in (("fs-vendor", "0x195"), ("fs-product", "0xFFFFFFFF"), ("fs-revision", "0xFFFFFFFF")):
                browser.find_element(By.ID, field).send_keys(value)
            browser.find_element(By.CSS_SELECTOR, "#form-lss-fast-scan button").click()
            found = wait_for(browser, lambda d: "frames" in d.find_element(By.ID, "result-lss-fast-scan").text
                             and d.find_element(By.ID, "result-lss-fast-scan").text, "the fast scan")  # fmt: skip
            assert found.startswith("found 0x00000195:0xFFFFFFFF:0xFFFFFFFF:0x00002300\n"), found
            assert "the address can be used in the LSS inquiry" in found

        await run(check)
