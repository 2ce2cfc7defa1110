"""The bus monitor page in a real browser (headless Chromium via selenium) against a running
gateway with simulated devices: frames of the bus appear live in CANopen words, a filter by node
and kind is applied (rows already shown are hidden, new ones come filtered from the gateway),
an EMCY shows the device's text, pause closes the stream (the gateway's reader tap is removed)
and resume says what was not recorded, and the page fits 1280 px.

Selenium blocks, so its calls run in a worker thread while the gateway runs on the test's event
loop; every wait is a WebDriverWait on page content."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.browser.chromium import BrowserUnavailable, chromium
from tests.browser.test_web_console import gateway, run, wait_for
from tests.browser.test_web_first_hour import OVERFLOW_JS
from tests.helpers import wait_until

pytestmark = pytest.mark.slow

#: the visible rows of the frames table: [kind, node, service, decoded text]
ROWS_JS = """return [...document.querySelectorAll('#frames tbody tr[data-kind]')]
  .filter(r => !r.hidden).map(r => [r.dataset.kind, r.dataset.node, r.cells[3].textContent,
                                    r.cells[4].textContent]);"""


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    try:
        with chromium(1280, 1000) as driver:
            yield driver
    except BrowserUnavailable as exc:
        pytest.skip(f"browser tests need a working headless Chromium: {exc}")


def rows(driver: Any) -> list[list[str]]:
    return driver.execute_script(ROWS_JS)


async def test_the_monitor_shows_frames_live_and_filters_by_node_and_kind(browser: Any) -> None:
    async with gateway() as (gw, base):
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support.ui import Select

        def open_page() -> list[str]:
            browser.set_window_size(1280, 1000)
            browser.get(base + "/monitor")
            wait_for(browser, lambda d: d.find_element(By.ID, "conn").text == "live", "live")
            wait_for(
                browser,
                lambda d: any(r[:3] == ["pdo", "wire", "TPDO1"] and r[3].startswith("position=")
                              for r in rows(d)),
                "a TPDO of wire with its signal names",
            )  # fmt: skip
            wait_for(browser, lambda d: any(r[0] == "heartbeat" for r in rows(d)), "heartbeats")
            wait_for(browser, lambda d: "shown" in d.find_element(By.ID, "mon-status").text, "status")
            return browser.execute_script(OVERFLOW_JS, ".table-wrap")

        assert await run(open_page) == []  # fits 1280 px
        assert len(gw.driver.frame_taps) == 1

        def filter_display_without_pdo() -> None:
            Select(browser.find_element(By.ID, "mon-node")).select_by_value("display")
            browser.find_element(By.CSS_SELECTOR, 'input[name="mkind"][value="pdo"]').click()
            # rows already shown are hidden at once
            assert all(r[1] == "display" and r[0] != "pdo" for r in rows(browser))
            wait_for(browser, lambda d: d.find_element(By.ID, "conn").text == "live", "live again")

        await run(filter_display_without_pdo)
        # the stream of both filters (the node's alone opens one first: an EMCY raised while
        # only that one is open goes to a stream the browser is closing, and is never shown)
        await wait_until(
            lambda: any(p.nodes == frozenset({125}) and p.kinds is not None
                        and "pdo" not in p.kinds and "emcy" in p.kinds
                        for p in gw.web.monitor.pages), 10,
            "the stream with both filters open in the gateway",
        )  # fmt: skip
        display = gw.sim.nodes["display"]
        # AP05 manual 5.5.1 table 31: FF12h speed error
        gw.sim.runner.call(lambda now: display.raise_emcy(0xFF12, 0x81, now=now))

        def check_filtered() -> None:
            wait_for(
                browser,
                lambda d: any(r[0] == "emcy" and "Speed error" in r[3] for r in rows(d)),
                "the display's EMCY with its text",
            )
            wait_for(browser, lambda d: any(r[0] == "heartbeat" for r in rows(d)), "heartbeats")
            shown = rows(browser)
            assert shown and all(r[1] == "display" and r[0] != "pdo" for r in shown)
            # what the gateway sent after the filter changed carries no other node at all
            nodes = browser.execute_script(
                "return [...document.querySelectorAll('#frames tbody tr[data-kind]')]"
                ".slice(0, 3).map(r => r.dataset.node)"
            )
            assert set(nodes) == {"display"}

        await run(check_filtered)


async def test_pause_closes_the_stream_and_resume_says_what_was_not_recorded(browser: Any) -> None:
    async with gateway() as (gw, base):
        from selenium.webdriver.common.by import By

        def open_page() -> None:
            browser.get(base + "/monitor?node=wire")
            wait_for(browser, lambda d: rows(d), "frames")
            assert browser.find_element(By.ID, "mon-node").get_attribute("value") == "wire"
            assert {r[1] for r in rows(browser)} == {"wire"}

        await run(open_page)
        await run(lambda: browser.find_element(By.ID, "mon-pause").click())
        await wait_until(lambda: gw.driver.frame_taps == (), 10, "the reader's tap removed")

        def resume() -> None:
            b = browser.find_element(By.ID, "mon-pause")
            assert b.text == "Resume" and b.get_attribute("aria-pressed") == "true"
            assert browser.find_element(By.ID, "conn").text == "paused"
            b.click()
            wait_for(browser, lambda d: d.find_element(By.ID, "conn").text == "live", "live")
            notes = [n.text for n in browser.find_elements(By.CSS_SELECTOR, "#frames tbody tr.note")]
            assert any(n.startswith("paused from ") and "not recorded" in n for n in notes)

        await run(resume)
        assert len(gw.driver.frame_taps) == 1


async def test_with_a_token_the_monitor_asks_for_it_once_and_then_shows_frames(browser: Any) -> None:
    """The operators' token (web.token): the page asks for it, logs in (the session cookie the
    event stream then carries) and shows the bus; a wrong token is asked again."""
    from tests.browser.test_web_console import TOKEN

    async with gateway(writes=True) as (gw, base):
        from selenium.webdriver.common.by import By
        from selenium.webdriver.support import expected_conditions as ec

        def unlock() -> None:
            browser.delete_all_cookies()  # no session yet (the tab's storage holds no token either)
            browser.get(base + "/monitor")
            wait_for(browser, ec.alert_is_present(), "the token prompt")
            browser.switch_to.alert.send_keys("wrong-token-0000")
            browser.switch_to.alert.accept()
            wait_for(browser, ec.alert_is_present(), "the prompt again after a wrong token")
            browser.switch_to.alert.send_keys(TOKEN)
            browser.switch_to.alert.accept()
            wait_for(browser, lambda d: d.find_element(By.ID, "conn").text == "live", "live")
            wait_for(browser, lambda d: any(r[0] == "heartbeat" for r in rows(d)), "heartbeats")

        await run(unlock)
        assert gw.web.monitor.pages  # the stream is open: the cookie was accepted
