"""The console's HTML pages, put together once when the console loads its static files: one shell
(``static/shell.html``: the head, the top bar with the navigation and the connection status,
``console.js``) around each page's own part (``static/<page>.html``: what its ``<main>``
holds). What differs from page to page is in ``PAGES`` (title, extra style sheets and scripts,
the ``data-page`` name ``console.js`` starts the page's code from, whether the page opens a live
stream) and ``NAV`` (the links; a page's own link carries ``aria-current="page"``).

The commissioning link is ``hidden`` on every other page: that page exists only with
``web.writes: true``, which ``console.js`` learns from ``/api/overview`` (it shows the link then,
and removes it otherwise).

Imports: the standard library only.
"""

from __future__ import annotations

from dataclasses import dataclass
from string import Template

#: the shell's file in ``static/``; not served itself
SHELL = "shell.html"


@dataclass(frozen=True)
class Page:
    """One page: ``static/<file>`` holds what its ``<main>`` holds, the rest comes from the shell."""

    file: str
    name: str  # <body data-page>: which page console.js runs
    title: str  # after "canopen-gateway: " in <title>
    styles: tuple[str, ...] = ()  # style sheets besides console.css
    scripts: tuple[str, ...] = ()  # scripts loaded before console.js
    live: bool = True  # opens a live stream: the status says "connecting" until it is open


@dataclass(frozen=True)
class NavLink:
    """A link of the top bar's navigation to the page named ``page``."""

    href: str
    text: str
    page: str
    id: str = ""  # for console.js
    writes_only: bool = False  # hidden until console.js knows web.writes is on


PAGES = (
    Page("index.html", "index", "overview"),
    Page(
        "node.html",
        "node",
        "node",
        styles=("/static/uPlot.min.css",),
        scripts=("/static/uPlot.iife.min.js",),  # the trend charts
    ),
    Page("commission.html", "commission", "commissioning", live=False),
    Page("events.html", "events", "events"),
    Page("monitor.html", "monitor", "bus monitor"),
    Page("notfound.html", "notfound", "not found", live=False),  # a node page of no node: 404
)

NAV = (
    NavLink("/", "Overview", "index"),
    NavLink("/events", "Events", "events"),
    NavLink("/monitor", "Bus monitor", "monitor"),
    NavLink("/commissioning", "Commissioning", "commission", id="nav-commission", writes_only=True),
)


def _nav_line(link: NavLink, page: Page) -> str:
    current = link.page == page.name
    attrs = f'href="{link.href}"'
    if link.id:
        attrs += f' id="{link.id}"'
    if current:
        attrs += ' aria-current="page"'
    elif link.writes_only:
        attrs += " hidden"
    return f"    <a {attrs}>{link.text}</a>\n"


def render(shell: str, page: Page, main: str) -> str:
    """The whole HTML of ``page``: ``shell`` filled with the page's settings and ``main``."""
    return Template(shell).substitute(
        title=page.title,
        styles="".join(f'<link rel="stylesheet" href="{href}">\n' for href in page.styles),
        page=page.name,
        nav="".join(_nav_line(link, page) for link in NAV),
        conn="connecting" if page.live else "",
        main=main,
        scripts="".join(f'<script src="{src}"></script>\n' for src in page.scripts),
    )


def fill_pages(files: dict[str, bytes]) -> None:
    """Replace each page's own part in ``files`` (static file name -> content) by its whole HTML,
    and drop the shell."""
    shell = files.pop(SHELL).decode()
    for page in PAGES:
        files[page.file] = render(shell, page, files[page.file].decode()).encode()
