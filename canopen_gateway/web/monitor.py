"""The console's bus monitor (``/monitor``): the frames the gateway receives on its own bus, in
CANopen words, live, filtered by node and kind, at most ``MAX_LINES_PER_S`` lines a second.

Rule 1 (the CAN reader thread): the one hand-off is ``FrameMonitor.on_frame``. It is installed
as a tap of the driver (``add_tap``) only while a monitor page is open; otherwise the reader pays one
attribute check per frame. While installed, it appends the raw ``(timestamp, COB-ID, data,
RTR, 29-bit)`` tuple to a bounded deque (``HANDOFF_MAX`` frames; older frames are counted as
lost if the loop falls that far behind) and calls ``loop.call_soon_threadsafe`` only when no
hand-off is armed, through ``canopen_gateway.web.live``'s ``Handoff``: the loop takes the whole batch and stays armed
for ``HANDOFF_PERIOD_S`` while frames flow, so a saturated bus costs at most
``1 / HANDOFF_PERIOD_S`` wake-ups a second. Nothing is decoded or formatted on the reader thread.

Rule 2 (the event loop): ``_take`` classifies each frame of the batch (kind and node id: a dict
lookup by COB-ID after its first frame), applies each page's filters, then each page's budget:
the first ``MAX_LINES_PER_S`` matching frames of each second are shown, the rest of that second
are counted and the page gets one "skipped" line for them. Only frames that are shown are
decoded (``canopen_gateway.northbound.frames.FrameDecoder``, once per frame whatever the number of pages).

Rule 3: a page is a bounded queue of lines (``MAX_PENDING``, the size of the page's own ring)
written by its pump (the console's one, ``canopen_gateway.web.live.stream_sse``) at most ``1 / SEND_INTERVAL_S`` times a second, each write with a status
(shown, skipped, lost; once a second when no line comes). A page whose socket does not drain is skipped (its queue drops
the oldest lines and counts them) and disconnected after ``SLOW_CLIENT_LIMIT_S`` (``web.live``'s).

Frames the gateway sends are not tapped (they leave through the sender thread): the page shows
what the gateway receives, as ``canopen-gateway monitor`` on a second connection shows both.

Several CAN networks: one ``FrameMonitor`` per network (``NetworkMonitors``), the page's
``?network=`` chooses.

Imports: config, http.server (the request and its answers), northbound.frames (the decoder,
node and kind filters), web.access (the per-client slots of the pages), web.live
(the SSE framing, its limits and its pump, ``stream_sse``), runtime.turns (each write in its turn on the
event loop: the PLC first). Never bus/ (the driver is given as an object with a
``add_tap`` / ``remove_tap``), modbus/ or zenoh_bridge/.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections import deque
from collections.abc import Callable, Iterable
from http import HTTPStatus
from typing import Any, Protocol

from canopen_gateway.config import Config
from canopen_gateway.http.server import Request, Response, Stream, StreamOut
from canopen_gateway.northbound.frames import KINDS, Decoded, FrameDecoder, kind_filter, node_filter
from canopen_gateway.runtime.turns import LoopTurns
from canopen_gateway.web.access import ClientSlots
from canopen_gateway.web.live import Handoff, sse, stream_sse

log = logging.getLogger("gateway.web")

MAX_LINES_PER_S = 200  # per page: more than the demo sends, far below a saturated bus
MAX_PENDING = 500  # lines waiting for one page; also the page's ring
HANDOFF_MAX = 20_000  # raw frames between two takes (2 s of a saturated 1 Mbit/s bus)
HANDOFF_PERIOD_S = 0.05
SEND_INTERVAL_S = 0.1
STATUS_PERIOD_S = 1.0
MAX_PAGES = 8

#: (wall-clock timestamp, COB-ID, data, remote frame, 29-bit identifier): what the reader keeps
RawFrame = tuple[float, int, bytes, bool, bool]


class FrameSource(Protocol):
    """The bus driver as the monitor sees it: a tap called by its reader with every frame."""

    def add_tap(self, tap: Callable[[Any], None]) -> None: ...

    def remove_tap(self, tap: Callable[[Any], None]) -> None: ...


class TooManyPages(Exception):
    pass


class MonitorPage:
    """One open monitor page: its filters, its budget and what waits to be sent."""

    __slots__ = ("nodes", "kinds", "lines", "wake", "window_start", "window_lines", "shown",
                 "skipped", "dropped", "matched")  # fmt: skip

    def __init__(self, nodes: frozenset[int] | None, kinds: frozenset[str] | None):
        self.nodes = nodes  # None: every node (and broadcasts)
        self.kinds = kinds  # None: every kind
        self.lines: deque[dict[str, Any]] = deque(maxlen=MAX_PENDING)
        self.wake = asyncio.Event()
        self.window_start = float("-inf")  # the current second of the budget (loop clock)
        self.window_lines = 0
        self.matched = 0  # frames that passed the filters
        self.shown = 0  # lines queued for the page
        self.skipped = 0  # matching frames over the budget
        self.dropped = 0  # lines the page did not read in time (its queue was full)

    def wants(self, kind: str, node_id: int | None) -> bool:
        return (self.kinds is None or kind in self.kinds) and (
            self.nodes is None or node_id in self.nodes
        )

    def queue(self, item: dict[str, Any]) -> None:
        if len(self.lines) == MAX_PENDING:
            self.dropped += 1
        self.lines.append(item)

    def status(self, lost: int) -> dict[str, int]:
        return {
            "matched": self.matched,
            "shown": self.shown,
            "skipped": self.skipped,
            "dropped": self.dropped,
            "lost": lost,
            "max_lines_per_s": MAX_LINES_PER_S,
        }


class FrameMonitor:
    """The tap, the hand-off and the pages (see the module docstring)."""

    def __init__(
        self,
        cfg: Config,
        decoder: FrameDecoder,
        source: FrameSource | None,
        *,
        clock: Callable[[], float] | None = None,
        max_pages: int = MAX_PAGES,
    ):
        self.cfg = cfg
        self.source = source
        self.max_pages = max_pages
        self._clock = clock
        self.pages: set[MonitorPage] = set()
        self._decoder = decoder  # the config's resolved nodes' (built by the application)
        self._class: dict[int, tuple[str, int | None, str | None]] = {}  # COB-ID -> kind, id, name
        self.handoff = Handoff(self._swap, self._deliver, HANDOFF_PERIOD_S)
        self._lock = self.handoff.lock
        self._ring: deque[RawFrame] = deque(maxlen=HANDOFF_MAX)
        self.tapped = 0  # frames the reader appended (under the lock)
        self.taken = 0  # frames the loop took
        self.decoded = 0  # frames decoded (on the loop)

    # ------------------------------------------------------------------ lifecycle
    @property
    def handoffs(self) -> int:
        """``call_soon_threadsafe`` calls made by the reader thread."""
        return self.handoff.handoffs

    @property
    def batches(self) -> int:
        """Batches taken on the loop."""
        return self.handoff.batches

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        self.handoff.loop = loop

    def detach(self) -> None:
        for page in list(self.pages):
            self.close(page)
        self.handoff.loop = None

    def decoder(self) -> FrameDecoder:
        return self._decoder

    def parse_filters(
        self, nodes: Iterable[str], kinds: Iterable[str]
    ) -> tuple[frozenset[int] | None, frozenset[str] | None]:
        """Filters from the page's query; ValueError in words for an unknown node or kind."""
        node_items = [n for n in nodes if n]
        kind_items = [k for k in kinds if k]
        ids = frozenset(node_filter(self.cfg, node_items)) if node_items else None
        ks = frozenset(kind_filter(kind_items)) if kind_items else None
        return ids, ks

    def refusal(self) -> str | None:
        """Why no page can be opened now, or None."""
        if self.source is None:
            return "this gateway has no bus to monitor"
        if len(self.pages) >= self.max_pages:
            return f"at most {self.max_pages} monitor pages at a time"
        return None

    def open(
        self, nodes: frozenset[int] | None = None, kinds: frozenset[str] | None = None
    ) -> MonitorPage:
        """A new page; the first one installs the tap."""
        refused = self.refusal()
        if refused is not None:
            raise TooManyPages(refused)
        self.decoder()  # built once, on the loop, before any frame needs it
        page = MonitorPage(nodes, kinds)
        assert self.source is not None  # refusal() said so otherwise
        if not self.pages:  # the first page: read by the reader thread from its next frame
            self.source.add_tap(self.on_frame)
        self.pages.add(page)
        return page

    def close(self, page: MonitorPage) -> None:
        """A page went away; the last one removes the tap."""
        self.pages.discard(page)
        if not self.pages and self.source is not None:
            self.source.remove_tap(self.on_frame)  # removing it twice changes nothing
            with self._lock:
                self.taken += len(self._ring)  # not lost: nobody is watching any more
                self._ring.clear()

    @property
    def lost(self) -> int:
        """Frames the reader appended that the loop never took (the hand-off ring overflowed)."""
        with self._lock:
            return self.tapped - self.taken - len(self._ring)

    # ------------------------------------------------------------------ hand-off
    def on_frame(self, msg: Any) -> None:
        """The tap: CAN reader thread, one frame (a ``can.Message``). Never decodes."""
        raw = (msg.timestamp, msg.arbitration_id, bytes(msg.data), msg.is_remote_frame,
               msg.is_extended_id)  # fmt: skip
        h = self.handoff
        with h.lock:
            self._ring.append(raw)
            self.tapped += 1
            if not h.arm():
                return
        h.wake()

    def _swap(self) -> list[RawFrame]:
        """Under the hand-off's lock, on the loop: the frames appended since the last take."""
        batch = list(self._ring)
        self._ring.clear()
        self.taken += len(batch)
        return batch

    def _deliver(self, batch: list[RawFrame]) -> None:
        """On the loop: show the batch on the open pages."""
        if self.pages:
            self.show(batch)

    def _now(self) -> float:
        if self._clock is not None:
            return self._clock()
        loop = self.handoff.loop
        return loop.time() if loop is not None else 0.0

    def classify(self, cob_id: int, data: bytes, rtr: bool, ext: bool) -> tuple[str, int | None, str | None]:
        """Kind, node id and node name of a frame: by COB-ID (the NMT frame by its data)."""
        if ext:
            return ("other", None, None)
        c = self._class.get(cob_id)
        if c is None:
            d = self.decoder().decode(cob_id, data, rtr)
            c = (d.kind, d.node_id, d.node)
            if cob_id != 0x000:  # an NMT command's node is in its data
                self._class[cob_id] = c
        return c

    def show(self, batch: Iterable[RawFrame]) -> None:
        """Filters, budget, then decoding of what is shown; wakes the pages that got lines."""
        now = self._now()
        pages = list(self.pages)
        for page in pages:
            if now - page.window_start >= 1.0:
                page.window_start = now
                page.window_lines = 0
        touched: set[MonitorPage] = set()
        for frame in batch:
            ts, cob_id, data, rtr, ext = frame
            kind, node_id, _ = self.classify(cob_id, data, rtr, ext)
            line: dict[str, Any] | None = None
            for page in pages:
                if not page.wants(kind, node_id):
                    continue
                page.matched += 1
                if page.window_lines >= MAX_LINES_PER_S:
                    page.skipped += 1
                    last = page.lines[-1] if page.lines else None
                    if last is not None and "skipped" in last:
                        last["skipped"] += 1
                    else:
                        page.queue({"skipped": 1, "ts": ts})
                    touched.add(page)
                    continue
                page.window_lines += 1
                if line is None:
                    line = self.line(ts, cob_id, data, rtr, ext)
                page.queue(line)
                page.shown += 1
                touched.add(page)
        for page in touched:
            page.wake.set()

    def line(self, ts: float, cob_id: int, data: bytes, rtr: bool, ext: bool) -> dict[str, Any]:
        """One frame as the page shows it (decoded here, on the loop)."""
        self.decoded += 1
        if ext:
            d = Decoded("other", None, None, "29-bit frame", data.hex(" ") or "(no data)")
        else:
            d = self.decoder().decode(cob_id, data, rtr)
        return {
            "ts": ts,
            "dir": "rx",
            "cob_id": f"{cob_id:08X}" if ext else f"{cob_id:03X}",
            "data": "remote request" if rtr else data.hex(" "),
            "kind": d.kind,
            "node_id": d.node_id,
            "node": d.node,
            "service": d.service,
            "text": d.text,
        }

    # ------------------------------------------------------------------ one page
    def hello(self, page: MonitorPage) -> dict[str, Any]:
        names = {n.name: n.node_id for n in self.cfg.nodes}
        return {
            "kinds": list(KINDS),
            "nodes": names,
            "filter": {
                "node": sorted(page.nodes) if page.nodes is not None else None,
                "kind": sorted(page.kinds) if page.kinds is not None else None,
            },
            "max_lines_per_s": MAX_LINES_PER_S,
            "ring": MAX_PENDING,
            "direction": "received",
        }

    async def pump(
        self,
        page: MonitorPage,
        out: StreamOut,
        turns: LoopTurns | None = None,
    ) -> None:
        """Write the page's lines until the browser goes away (or does not read for
        ``web.live.SLOW_CLIENT_LIMIT_S``): at most one write every ``SEND_INTERVAL_S``, a status at least
        every ``STATUS_PERIOD_S``."""
        last_status = float("-inf")

        def turn(now: float) -> bytes:
            nonlocal last_status
            chunks = []
            if page.lines:
                lines = list(page.lines)
                page.lines.clear()
                chunks.append(sse("frames", lines))
            if chunks or now - last_status >= STATUS_PERIOD_S:
                chunks.append(sse("status", page.status(self.lost)))
                last_status = now
            return b"".join(chunks)

        try:
            await stream_sse(
                out,
                page.wake,
                turn,
                lambda: last_status + STATUS_PERIOD_S,
                interval_s=SEND_INTERVAL_S,
                who="bus monitor page",
                first=sse("hello", self.hello(page)),
                turns=turns,
            )
        finally:
            self.close(page)


class NetworkMonitors:
    """One ``FrameMonitor`` per CAN network (each on its network's driver, with its network's
    decoder: node ids are a network's own); a page watches one network, ``?network=NAME``,
    the first by default."""

    def __init__(self, monitors: dict[str, FrameMonitor]):
        assert monitors, "a gateway has at least one network"
        self.by_network = monitors
        #: the first network's (the only one of a single-network gateway)
        self.first = next(iter(monitors.values()))

    @property
    def names(self) -> list[str]:
        return list(self.by_network)

    def sources(self) -> dict[str, FrameSource | None]:
        """Each network's tap source (its bus driver), by network name."""
        return {name: m.source for name, m in self.by_network.items()}

    def attach(self, loop: asyncio.AbstractEventLoop) -> None:
        for m in self.by_network.values():
            m.attach(loop)

    def detach(self) -> None:
        for m in self.by_network.values():
            m.detach()

    def stream(
        self,
        request: Request,
        turns: LoopTurns | None,
        gate: Callable[[Request], Response | None],
        slots: ClientSlots,
    ) -> Response | Stream:
        """``GET /api/monitor/stream[?network=&node=&kind=]``: the network's frames as
        server-sent events; 400 for an unknown network, node or kind, the ``gate``'s answer
        (the operators' token), 503 past the pages or past the client's own (``slots``:
        per client address, every network's pages together)."""
        name = request.query.get("network") or None
        monitor = self.first if name is None else self.by_network.get(name)
        try:
            if monitor is None:
                raise ValueError(f"network: no network named {name!r}; networks: {', '.join(self.names)}")
            nodes, kinds = monitor.parse_filters(
                request.query.get("node", "").split(","), request.query.get("kind", "").split(",")
            )
        except ValueError as exc:
            message = str(exc).replace("--node ", "node: ").replace("--kind ", "kind: ")
            return _json(HTTPStatus.BAD_REQUEST, {"error": "bad_request", "message": message})
        refused = gate(request)
        if refused is not None:
            return refused
        if request.method == "HEAD":
            return Response(HTTPStatus.OK, b"", "text/event-stream")
        busy = monitor.refusal()
        client = request.client
        if busy is None and slots.full(client):
            busy = f"at most {slots.per_client} monitor pages per client address"
        if busy is not None:
            return _json(HTTPStatus.SERVICE_UNAVAILABLE, {"error": "busy", "message": busy})

        async def body(out: StreamOut) -> None:
            # opened here, not before the headers are written: a page is closed by its pump
            if not slots.take(client):  # another page of this client came first
                return
            try:
                try:
                    page = monitor.open(nodes, kinds)
                except TooManyPages as exc:  # another page came first since refusal()
                    out.write(b"event: error\ndata: " + json.dumps(str(exc)).encode() + b"\n\n")
                    return
                await monitor.pump(page, out, turns=turns)
            finally:
                slots.give(client)

        return Stream("text/event-stream", body)


def _json(status: HTTPStatus, doc: Any) -> Response:
    body = (json.dumps(doc, default=str, separators=(",", ":")) + "\n").encode()
    return Response(status, body, "application/json")
