"""The console's first-hour features in a real browser (headless Chromium via selenium) against a
running gateway with simulated devices: trends drawn by the vendored chart library from good
samples and shown stale when the node is unplugged with the page's fault buttons (and good after
it is plugged back), the read button of a configuration object, the event log with its filters,
the register map link, and pages that fit 1280 px without a horizontal scroll bar.

Selenium blocks, so its calls run in a worker thread while the gateway runs on the test's event
loop; every wait is a WebDriverWait on page content."""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Iterator
from typing import Any

import pytest

from tests.browser.chromium import BrowserUnavailable, chromium
from tests.browser.test_web_console import gateway, run, value_cell, wait_for

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    try:
        with chromium(1280, 1000) as driver:
            yield driver
    except BrowserUnavailable as exc:
        pytest.skip(f"browser tests need a working headless Chromium: {exc}")


def trend_caption(driver: Any, signal: str) -> str:
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException
    from selenium.webdriver.common.by import By

    try:
        return driver.find_element(
            By.CSS_SELECTOR, f'figure.trend[data-signal="{signal}"] .trend-last'
        ).text
    except (NoSuchElementException, StaleElementReferenceException):
        return ""


def state_fact(driver: Any, name: str) -> str:
    """A value of the node page's State card (``Presence``, ``Status``...)."""
    return driver.execute_script(
        """const dts = [...document.querySelectorAll('#node-state dt')];
           const dt = dts.find(d => d.textContent === arguments[0]);
           return dt ? dt.nextElementSibling.textContent : '';""",
        name,
    )


#: the last sample of a trend: [good value, stale value] (null where the series has none)
LAST_JS = """const c = trendCharts[arguments[0]]; const n = c.t.length;
return n ? [c.good[n - 1], c.stale[n - 1], c.plot.data[0].length] : null;"""


async def test_trends_turn_stale_when_the_fault_buttons_unplug_the_node_and_good_after(
    browser: Any,
) -> None:
    async with gateway() as (gw, base):
        from selenium.webdriver.common.by import By

        def click(action: str) -> None:
            browser.find_element(By.CSS_SELECTOR, f'#fault-buttons button[data-fault="{action}"]').click()

        def check() -> None:
            browser.get(base + "/node/wire")
            wait_for(browser, lambda d: trend_caption(d, "position").endswith("mm (good)"), "good trend")
            assert browser.find_elements(By.CSS_SELECTOR, 'figure.trend[data-signal="position"] canvas')
            good, stale, points = browser.execute_script(LAST_JS, "position")
            assert good is not None and stale is None and points >= 1
            # every sample once, in time order (the stream may repeat what the page fetched)
            wait_for(browser, lambda d: d.execute_script(
                "return trendCharts.position.t.length") >= 4, "a few samples")
            times = browser.execute_script("return trendCharts.position.t")
            assert times == sorted(set(times))
            # the trends and the fault buttons come before the signals table
            order = browser.execute_script(
                "return [...document.querySelectorAll('main > section')].map(s => s.id || s.getAttribute('aria-labelledby'))"
            )
            assert order.index("sec-trends") < order.index("h-signals")
            assert "virtual bus" in browser.find_element(By.ID, "fault-rule").text
            click("unplug")
            wait_for(browser, lambda d: state_fact(d, "Presence").endswith("lost"), "lost")
            wait_for(browser, lambda d: trend_caption(d, "position").endswith("(stale)"), "stale trend")
            good, stale, _ = browser.execute_script(LAST_JS, "position")
            assert good is None and stale is not None  # never drawn as good
            assert "unplugged" in browser.find_element(By.ID, "fault-state").text
            with urllib.request.urlopen(base + "/api/events?kind=warning&node=wire", timeout=5) as r:
                texts = [e["text"] for e in json.loads(r.read())["events"]]
            assert "simulated fault: wire unplug (from web 127.0.0.1, the web console as its client says)" in texts
            click("plug")
            wait_for(browser, lambda d: state_fact(d, "Presence").endswith("alive"), "alive")
            wait_for(browser, lambda d: trend_caption(d, "position").endswith("(good)"), "good again")

        await run(check)


async def test_the_read_button_shows_the_value_of_a_configuration_object(browser: Any) -> None:
    async with gateway() as (gw, base):
        from selenium.webdriver.common.by import By

        gw.sim.runner.call(lambda now: gw.sim.nodes["wire"].set(0x6401, 1, 4321))

        def check() -> None:
            browser.get(base + "/node/wire")
            button = wait_for(
                browser,
                lambda d: d.find_elements(By.CSS_SELECTOR, 'button[data-read="work_area_1_low_limit"]'),
                "a read button",
            )[0]
            assert value_cell(browser, "work_area_1_low_limit") == "read by SDO on request"
            assert not browser.find_elements(By.CSS_SELECTOR, 'button[data-read="position"]')
            button.click()
            wait_for(
                browser,
                lambda d: value_cell(d, "work_area_1_low_limit").startswith("432.1 mm — read"),
                "the value read",
            )
            link = browser.find_element(By.ID, "registers-csv")
            assert link.get_attribute("href") == base + "/api/registers.csv"

        await run(check)


async def test_the_event_log_updates_live_and_filters_by_node_and_kind(browser: Any) -> None:
    async with gateway() as (gw, base):
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import Select

        def rows() -> list[tuple[str, str]]:
            found = browser.execute_script(
                "return [...document.querySelectorAll('#events tbody tr[data-kind]')]"
                ".map(r => [r.dataset.kind, r.cells[2].textContent])"
            )
            return [tuple(r) for r in found]

        def check_empty() -> None:
            browser.get(base + "/events")
            wait_for(browser, lambda d: d.find_element(By.ID, "conn").text == "live", "live")

        await run(check_empty)
        display = gw.sim.nodes["display"]
        gw.sim.runner.call(lambda now: display.raise_emcy(0xFF00, 0x81, now=now))
        wire = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: wire.silence())

        def check() -> None:
            wait_for(browser, lambda d: ("emcy", "display") in rows(), "the EMCY, live")
            wait_for(browser, lambda d: ("state", "wire") in rows(), "wire lost, live")
            browser.find_element(By.CSS_SELECTOR, 'input[name="kind"][value="emcy"]').click()
            assert all(kind != "emcy" for kind, _ in rows())
            Select(browser.find_element(By.ID, "ev-node")).select_by_value("wire")
            assert rows() and all(node == "wire" for _, node in rows())
            assert "events shown" in browser.find_element(By.ID, "ev-count").text

        await run(check)


#: horizontal overflow: the page, and every table wrapper of the page's own sections
OVERFLOW_JS = """
const out = [];
if (document.documentElement.scrollWidth > document.documentElement.clientWidth) out.push('page');
for (const w of document.querySelectorAll(arguments[0])) {
  if (w.scrollWidth > w.clientWidth + 1) out.push(w.id || w.className);
}
return out;
"""


async def test_the_new_sections_fit_1280_px(browser: Any) -> None:
    async with gateway() as (gw, base):
        from selenium.webdriver.common.by import By

        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].raise_emcy(0xFF00, 0x81, now=now))

        def check() -> list[str]:
            browser.set_window_size(1280, 1000)
            browser.get(base + "/events")
            wait_for(browser, lambda d: d.find_elements(By.CSS_SELECTOR, "#events tbody tr[data-kind]"), "events")
            problems = [f"/events: {x}" for x in browser.execute_script(OVERFLOW_JS, ".table-wrap")]
            browser.get(base + "/node/display")
            wait_for(browser, lambda d: d.find_elements(By.CSS_SELECTOR, "figure.trend canvas"), "trends")
            problems += [
                f"/node/display: {x}"
                for x in browser.execute_script(OVERFLOW_JS, "#sec-trends, #sec-faults, .trend-plot")
                if x != "page"  # the signals table is not one of these sections
            ]
            return problems

        assert await run(check) == []


def test_the_chart_library_is_vendored_with_its_licence() -> None:
    from importlib import resources

    static = resources.files("canopen_gateway.web").joinpath("static")
    js = static.joinpath("uPlot.iife.min.js").read_text()
    assert js.startswith("/*! https://github.com/leeoniya/uPlot (v1.6.32) */")
    licence = static.joinpath("uPlot.LICENSE.txt").read_text()
    assert "The MIT License" in licence and "Leon Sorokin" in licence
    assert json.dumps("uPlot")  # the console loads it from /static only (CSP default-src 'self')


#: fills the position trend with samples over ``arguments[0]`` seconds up to now (at a chart width
#: of ``arguments[1]`` px, when given), and after the chart has drawn returns each x-axis label
#: with its centre and its width (its widest line) in CSS pixels
AXIS_LABELS_JS = """const [windowS, widthPx, done] = arguments;
const c = trendCharts.position, now = Date.now() / 1000, n = 301;
if (widthPx) c.plot.setSize({ width: widthPx, height: 150 });
const t = [...Array(n).keys()].map(i => now - windowS + i * windowS / (n - 1));
c.t.splice(0, c.t.length, ...t);
c.good.splice(0, c.good.length, ...t.map((_, i) => i));
c.stale.splice(0, c.stale.length, ...t.map(() => null));
c.quality.splice(0, c.quality.length, ...t.map(() => 0));
c.plot.setData([c.t, c.good, c.stale]);
requestAnimationFrame(() => requestAnimationFrame(() => {
  const u = c.plot, ax = u.axes[0], ctx = u.ctx;
  ctx.save(); ctx.font = ax.font[0];
  const px = window.devicePixelRatio || 1;
  const width = (text) => Math.max(...text.split("\\n").map(l => ctx.measureText(l).width)) / px;
  const out = ax._splits.map((v, i) => [String(ax._values[i]), u.valToPos(v, "x"),
                                        width(String(ax._values[i]))]);
  ctx.restore();
  done(out);
}));"""


@pytest.mark.parametrize("width_px", [None, 240])
@pytest.mark.parametrize("window_s", [300, 120, 20])
async def test_the_time_axis_labels_of_a_trend_do_not_touch_at_1280_px(
    browser: Any, window_s: int, width_px: int | None
) -> None:
    """``9:01pm9:02pm``: each label of the time axis is apart from the next by a gap a reader
    sees (8 px at least), for the window the console keeps (300 s) and shorter ones, at the
    width the page gives a chart at 1280 px and at the narrowest a chart gets (240 px)."""
    async with gateway() as (gw, base):

        def check() -> list[list[Any]]:
            browser.get(base + "/node/wire")
            wait_for(browser, lambda d: trend_caption(d, "position").endswith("(good)"), "a trend")
            return list(browser.execute_async_script(AXIS_LABELS_JS, window_s, width_px))

        labels = await run(check)
    assert len(labels) >= 2, labels
    assert all(text.strip() for text, _, _ in labels), labels
    for (a, xa, wa), (b, xb, wb) in zip(labels, labels[1:], strict=False):
        gap_px = (xb - xa) - (wa + wb) / 2
        assert gap_px >= 8, f"{a!r} and {b!r} {gap_px:.1f} px apart: {labels}"
