"""The console's pages as served: the shell filled per page (``canopen_gateway.web.pages``), pure."""

from __future__ import annotations

import re
from importlib import resources

from canopen_gateway.web.console import _load_static
from canopen_gateway.web.pages import NAV, PAGES, SHELL


def test_every_page_file_is_served_whole_and_the_shell_is_not_served() -> None:
    static = resources.files("canopen_gateway.web").joinpath("static")
    html = {e.name for e in static.iterdir() if e.name.endswith(".html")}
    assert html - {SHELL} == {p.file for p in PAGES}
    files = _load_static()
    assert SHELL not in files
    for page in PAGES:
        text = files[page.file].decode()
        assert text.startswith("<!doctype html>") and text.endswith("</html>\n"), page.file
        assert "$" not in text, page.file
        assert f'<body data-page="{page.name}">' in text
        assert text.count("<main>") == 1 and text.count("</main>") == 1
        # console.js last, after the page's own scripts (uPlot on the node page)
        scripts = re.findall(r'<script src="([^"]+)"></script>', text)
        assert scripts == [*page.scripts, "/static/console.js"], page.file


def test_only_the_page_s_own_nav_link_is_current_and_commissioning_is_hidden_elsewhere() -> None:
    files = _load_static()
    for page in PAGES:
        block = re.search(r"<nav aria-label=\"Pages\">(.*?)</nav>", files[page.file].decode(), re.S)
        assert block is not None, page.file
        nav = dict(re.findall(r"<a href=\"([^\"]*)\"([^>]*)>", block.group(1)))
        assert list(nav) == [n.href for n in NAV], page.file
        current = [href for href, attrs in nav.items() if 'aria-current="page"' in attrs]
        own = [n.href for n in NAV if n.page == page.name]
        assert current == own, page.file  # the node page has no link of its own
        commission = nav["/commissioning"]
        assert 'id="nav-commission"' in commission
        assert ("hidden" in commission) == (page.name != "commission"), page.file
