"""The web console's event log: a bounded ring of recent events (EMCY, node state changes,
warnings and errors of the gateway's loggers) for the events page, with filters by node and kind.

Where events come from (nothing new is detected here; it records what the gateway already says):

- ``EventLog.on_health``: a health listener of the process image (called on the event loop by
  the nodes' owner). It compares the node's health with what it saw last and files ``state``
  events (presence, NMT state, lifecycle, guarding-bit link, outputs) and ``emcy`` events
  (each EMCY counted since, with its code and text).
- ``EventLogHandler``: a ``logging.Handler`` on the ``gateway`` logger at WARNING. Its ``emit``
  only formats the record's message and appends it (kinds ``warning`` and ``error``); the
  gateway's recurring problems are already rate-limited where they are logged
  (``canopen_gateway.runtime.ratelimit``), so the ring is not flooded by one noisy frame. A record is filed
  under a node when its message names a configured node as a word.

Rule: ``append`` is the one writer path, under a lock, because log records arrive from any
thread (the CAN reader, Zenoh's threads, the event loop). Readers copy under the same lock.
The ring keeps ``MAX_EVENTS``; ``seq`` numbers let a page ask for what is new.

Imports: image and states (types), web.views (words for states). Never bus/, modbus/,
zenoh_bridge/ with I/O.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

from canopen_gateway.image import NodeImage
from canopen_gateway.web.views import LINK_WORDS, NMT_WORDS

MAX_EVENTS = 500
KINDS = ("emcy", "state", "warning", "error")


@dataclass(frozen=True)
class Event:
    seq: int
    ts: float  # wall clock, seconds since the epoch
    kind: str  # one of KINDS
    node: str | None
    text: str

    def doc(self) -> dict[str, Any]:
        return asdict(self)


def _health_view(node: NodeImage) -> dict[str, str]:
    h = node.health
    return {
        "presence": "alive" if h.alive else ("lost" if h.boot_count or h.loss_count else "not seen"),
        "NMT state": NMT_WORDS.get(h.nmt_state, h.nmt_state.name.lower()),
        "lifecycle": h.lifecycle,
        "guarding-bit link": LINK_WORDS.get(h.link, str(h.link)),
        "outputs": h.outputs,
    }


class EventLog:
    """The ring and its two feeds (see the module docstring)."""

    def __init__(
        self,
        nodes: Iterable[str] = (),
        *,
        max_events: int = MAX_EVENTS,
        clock: Callable[[], float] = time.time,
    ):
        self.clock = clock
        self._ring: deque[Event] = deque(maxlen=max_events)
        self._lock = threading.Lock()
        self._seq = 0
        self.nodes = tuple(nodes)
        self._node_word = (
            re.compile(r"\b(" + "|".join(re.escape(n) for n in sorted(self.nodes, key=len, reverse=True)) + r")\b")
            if self.nodes
            else None
        )
        self._seen: dict[str, dict[str, str]] = {}  # event loop only (on_health)
        self._emcy_seen: dict[str, int] = {}

    # ------------------------------------------------------------------ writing
    def append(self, kind: str, node: str | None, text: str, ts: float | None = None) -> Event:
        with self._lock:
            self._seq += 1
            ev = Event(self._seq, self.clock() if ts is None else ts, kind, node, text)
            self._ring.append(ev)
        return ev

    def node_named_in(self, text: str) -> str | None:
        if self._node_word is None:
            return None
        m = self._node_word.search(text)
        return m.group(1) if m else None

    def watch(self, node: NodeImage) -> None:
        """Remember a node's current health without an event (at start)."""
        self._seen[node.name] = _health_view(node)
        self._emcy_seen[node.name] = node.health.emcy_count

    def on_health(self, node: NodeImage, what: str) -> None:
        """Health listener of the image (event loop)."""
        now_view = _health_view(node)
        before = self._seen.get(node.name)
        if before is not None:
            changes = [
                f"{k} {before[k]} -> {v}" for k, v in now_view.items() if before.get(k) != v
            ]
            if changes:
                self.append("state", node.name, f"{node.name}: " + ", ".join(changes))
        self._seen[node.name] = now_view
        h = node.health
        seen = self._emcy_seen.get(node.name, 0)
        if h.emcy_count > seen and h.last_emcy is not None:
            e = h.last_emcy
            more = h.emcy_count - seen - 1
            text = f"{node.name}: EMCY 0x{e.code:04X} {e.text}".rstrip()
            if e.code == 0:
                text = f"{node.name}: EMCY 0x0000 error reset"
            if more > 0:
                text += f" (and {more} more since the last event)"
            self.append("emcy", node.name, text, ts=e.timestamp or None)
        self._emcy_seen[node.name] = h.emcy_count

    # ------------------------------------------------------------------ reading
    @property
    def seq(self) -> int:
        return self._seq

    def since(
        self, after: int = 0, node: str | None = None, kinds: Iterable[str] | None = None
    ) -> list[Event]:
        want = None if kinds is None else frozenset(kinds)
        with self._lock:
            events = list(self._ring)
        return [
            e
            for e in events
            if e.seq > after
            and (node is None or e.node == node)
            and (want is None or e.kind in want)
        ]


class EventLogHandler(logging.Handler):
    """Appends the gateway's WARNING and ERROR records to an ``EventLog``; never logs itself."""

    def __init__(self, events: EventLog, level: int = logging.WARNING):
        super().__init__(level)
        self.events = events

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # a bad format string in a record: keep the raw message
            text = str(record.msg)
        kind = "error" if record.levelno >= logging.ERROR else "warning"
        self.events.append(kind, self.events.node_named_in(text), text, ts=record.created)
