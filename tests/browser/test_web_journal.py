"""The events page's Journal section in a real browser (headless Chromium via selenium): the
journal's EMCY events of the last hour are listed oldest first for the node chosen, a range in
the past shows none, and the CSV link carries the same range and filters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.app import Gateway
from tests.browser.test_web_console import browser, run, wait_for  # noqa: F401 - the fixture
from tests.helpers import free_port, gateway_of, make_config, node_operational, wait_until
from tests.integration.test_zenoh_history import raise_and_clear

pytestmark = pytest.mark.slow


async def started(tmp_path: Path) -> tuple[Gateway, str]:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        health={"port": free_port()},
        journal={"path": str(tmp_path / "journal")},
    )
    gw = gateway_of(cfg)
    await gw.start()
    await wait_until(lambda: node_operational(gw, "wire"), 8, "wire operational")
    return gw, f"http://127.0.0.1:{gw.health.port}"


def journal_rows(driver: Any, kinds: str) -> list[tuple[str, str, str]] | None:
    """The rows of the journal's table (kind, seq, text), read in one script call once the
    table shows the answer to a query of ``kinds`` (its ``data-query``); None before. The page
    replaces the rows whole with each answer: rows found one call before may be gone."""
    rows = driver.execute_script(
        """const t = document.getElementById("journal");
        if (!(t.dataset.query || "").split("&").includes("kind=" + encodeURIComponent(arguments[0]))) return null;
        return [...t.querySelectorAll("tbody tr[data-kind]")].map(
          (r) => [r.dataset.kind, r.cells[3].textContent, r.cells[4].textContent]);""",
        kinds,
    )
    return None if rows is None else [tuple(r) for r in rows]


async def test_the_journal_section_lists_a_range_and_links_its_csv(browser: Any, tmp_path) -> None:  # noqa: F811
    from selenium.webdriver.common.by import By

    gw, base = await started(tmp_path)
    try:
        raise_and_clear(gw, 1)
        await wait_until(lambda: gw.journal.counts.written >= 3, 5, "EMCY journaled")

        def emcy_only() -> list[tuple[str, str, str]]:
            browser.get(base + "/events")
            # the page's first answer shown: its code runs, the form's submit is its own now
            wait_for(browser, lambda d: d.execute_script('return document.getElementById("journal").dataset.query || null'), "the page's first journal answer")  # fmt: skip
            for box in browser.find_elements(By.CSS_SELECTOR, 'input[name="jkind"]'):
                if box.get_attribute("value") != "emcy":
                    box.click()
            browser.find_element(By.CSS_SELECTOR, "#journal-form button").click()
            return wait_for(browser, lambda d: journal_rows(d, "emcy"), "the journal's EMCY rows")

        rows = await run(emcy_only)
        assert {kind for kind, _, _ in rows} == {"emcy"}
        assert [(seq, text.split(" EMCY ")[1][:6]) for _, seq, text in rows] == [
            ("1", "0xFF05"),
            ("2", "0x0000"),
        ]
        href = await run(lambda: browser.find_element(By.ID, "jr-csv").get_attribute("href"))
        assert "/api/journal.csv?" in href and "kind=emcy" in href and "from=now" in href

        def past() -> str:
            f = browser.find_element(By.ID, "jr-from")
            f.clear()
            f.send_keys("2001-01-01T00:00:00Z")
            t = browser.find_element(By.ID, "jr-to")
            t.clear()
            t.send_keys("2001-01-02T00:00:00Z")
            browser.find_element(By.CSS_SELECTOR, "#journal-form button").click()
            return wait_for(
                browser,
                lambda d: (
                    d.find_element(By.ID, "jr-status").text.startswith("0 entries")
                    and d.find_element(By.ID, "jr-status").text
                ),
                "an empty range",
            )

        assert await run(past) == "0 entries"
    finally:
        await gw.stop()
