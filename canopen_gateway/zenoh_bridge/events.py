"""State and EMCY events as the bridge makes them, whatever the Zenoh session does: each event
gets the next ``seq`` of its key and a stamp (``journal.HybridClock``: the gateway's own clock,
never back, no session needed), is handed to the journal (with one) and queued for the
``zenoh-events`` thread (``sender.py``), which publishes it once it is committed or after
``EVENT_WAIT_S`` at most (the live path never waits longer for the disk), and keeps it while no
session is open (it goes out, in order, when one is).

``seq``: 1, 2, 3... per key; with a journal, after the highest the journal ever handed out on
the key (``Journal.last_seqs``: kept across trims, drops, damage and restarts); in a pair,
after the highest the other member published (``HeardSeq``).

Runs on the event loop (the master's health listener). Imports: journal, northbound.keys,
zenoh_bridge.pair, zenoh_bridge.payloads, zenoh_bridge.sender; image for types only. Never
zenoh, modbus/ nor bus/.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from canopen_gateway.journal import Entry, HybridClock, Journal, ntp64_of_ns
from canopen_gateway.northbound.keys import emcy_key, state_key
from canopen_gateway.zenoh_bridge.pair import HeardSeq
from canopen_gateway.zenoh_bridge.payloads import emcy_payload, state_fingerprint, state_payload
from canopen_gateway.zenoh_bridge.sender import ZenohSender

if TYPE_CHECKING:
    from canopen_gateway.image import NodeImage


class EventLog:
    """The events of every node (see the module docstring)."""

    def __init__(self, prefix: str, sender: ZenohSender, heard: HeardSeq, hlc: HybridClock) -> None:
        self.prefix = prefix
        self.sender = sender
        self.heard = heard
        #: the stamps of events (the journal's clock once there is one)
        self.hlc = hlc
        self.journal: Journal | None = None
        #: the last ``seq`` given per event key
        self.seq: dict[str, int] = {}
        self._last_state: dict[str, tuple[Any, ...]] = {}

    def use_journal(self, journal: Journal, keys: Iterable[str]) -> None:
        """Journal every event from now on; each key's ``seq`` goes on above the journal's."""
        self.journal = journal
        self.hlc = journal.hlc
        last = journal.last_seqs()
        for key in keys:
            if key in last:
                self.seq[key] = max(self.seq.get(key, 0), last[key])

    def on_health(self, node: NodeImage, what: str) -> None:
        """A node's health changed (``what``: ``emcy``, or anything else for its state)."""
        if what == "emcy":
            rec = node.health.last_emcy
            if rec is not None:
                payload = emcy_payload(node, rec, node.health.emcy_count)
                self.emit(emcy_key(self.prefix, node.name), node.name, "emcy", payload)
            return
        d = state_payload(node)
        fp = state_fingerprint(d)
        if self._last_state.get(node.name) != fp:
            self._last_state[node.name] = fp
            self.emit(state_key(self.prefix, node.name), node.name, "state", d)

    def emit(self, key: str, node: str, kind: str, payload: dict[str, Any]) -> None:
        seq = max(self.seq.get(key, 0), self.heard.get(key)) + 1
        self.seq[key] = seq
        payload["seq"] = seq
        data = json.dumps(payload).encode()
        ns = self.hlc.stamp()
        ticket = 0
        if self.journal is not None:
            ticket = self.journal.append(Entry(ntp64_of_ns(ns), kind, key, node, seq, data))
        self.sender.put_event(key, data, ns, ticket)

    def before_heard(self, key: str) -> int:
        """The highest ``seq`` known of an event key before a sample heard of the other member."""
        return max(self.heard.get(key), self.seq.get(key, 0))
