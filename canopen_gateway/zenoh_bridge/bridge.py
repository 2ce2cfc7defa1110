"""Zenoh bridge: owns the session; publishes the process image, node state and EMCY events, raw
PDOs on request, liveliness tokens per usable node and for the gateway, and declares the
queryable whose answers live in ``queries.py`` (``QueryService``).

Threads (started through the gateway's ``ThreadRegistry``: a thread that dies is reported and
turns /healthz not-ready, never silently):

* values are marked on the CAN reader thread right after the image was written; at the end of
  each burst of frames (the image's batch listener, when the reader has handled every frame
  already received, and every few frames while frames keep coming) the reader wakes the
  ``zenoh-publish`` thread (``sender.py``: one queued flush at a time, at most one per
  ``zenoh.batch_ms``), which publishes the *current* value of every marked signal (coalescing
  while it is behind). A Zenoh ``put`` releases the interpreter lock, so puts on the reader
  let the event loop in and made the reader wait for the lock back (frame -> Modbus p99 about 2x
  longer on a saturated bus: bench/RESULTS.md, the findings, "Cost per frame").
  ``publish: every`` signals are put by the reader for every frame. A signal's value, quality
  and policy are read and written under its own lock, whichever thread publishes, and a sample
  never follows a newer one;
  publications are counted per signal under that lock (raw PDOs per thread,
  ``threads.ThreadCount``) and summed when read;
* events (state, EMCY) are computed on the event loop when the master reports them
  (``events.py``: their ``seq`` and stamp, the journal, whether a session is open or not) and
  put by the ``zenoh-events`` thread in order, with congestion control BLOCK and priority
  INTERACTIVE_HIGH: never dropped, and a congested network never blocks the event loop nor
  holds the values back; with a journal each is published once committed, 200 ms at most;
* a housekeeping task on the event loop publishes held-back samples (max rate) and quality
  changes that no frame announces (stale by age);
* query callbacks run on zenoh threads and only queue the query for the ``zenoh-queries``
  thread (``worker.py``: bounded, fair between querying sessions, a full queue answered
  ``busy``), where ``QueryService`` answers reads of the image a reply at a time, giving way
  to the event loop (the Modbus server) between turns, and hands commands to the event loop
  (the command service).

Values and events go out through zenoh-ext advanced publishers (``zenoh.history``): each keeps
the last samples of its key (1,000 per event key, the last value per value key by default),
sends heartbeats with its last sequence number and announces itself, so an
``AdvancedSubscriber`` with history and recovery gets what it missed while a router or a WAN
link was down. Our payloads carry their own ``seq`` too, so a plain subscriber sees a gap.

Writes (``set``, SDO download, ``nmt``) pass ``zenoh.writes`` / ``zenoh.write_allow`` first
(``access.WriteGate``, in ``queries.py``); a refused one is answered ``forbidden``, counted and
logged (rate-limited), and nothing goes on the bus.

The session is opened before the bus (``open``): when a gateway with the same prefix is
already announced on the Zenoh network (its ``<prefix>/alive/_gateway`` token), the session
stays closed (``ZenohSession.problem`` says why, /healthz names it) and is retried in the
background while Modbus and the bus run. In client mode, with no router reachable, the gateway
starts anyway and the bridge retries in the background (0.5 s, 1 s, 2 s, then every 5 s). After a router restart zenoh reconnects by itself and
re-declares publishers, queryable and liveliness tokens.

The bridge is composed of: ``plan.py`` (what to publish, planned once: ``SignalPub``,
``PdoPub``, the reader's routes), ``events.py`` (``EventLog``), ``journaling.py`` (the value
history the journal keeps), ``session.py`` (``ZenohSession``, the session's lifecycle:
open, duplicate check, re-open, declarations, stop; it holds the session, publishers, tokens
and tasks, and the bridge calls it through its public methods), ``housekeeping.py`` (the
periodic refresh) and ``sender.py`` (the ``zenoh-publish`` and ``zenoh-events`` threads). The
per-frame path (the image's listeners, ``_ValueBatch``, ``offer``) stays here.

Imports: zenoh, commands, image, config, journal, runtime.ratelimit, runtime.threads, profiles.schema, northbound.keys,
northbound.scaling, zenoh_bridge.*. Never modbus/ (the catalogue gets Modbus addresses through a
function passed in by the app) and nothing of bus/ (nodes are known through the command
service).
"""

from __future__ import annotations

import asyncio
import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from canopen_gateway.commands import CommandService
from canopen_gateway.config import Config
from canopen_gateway.image import NodeImage, ProcessImage, SignalValue
from canopen_gateway.journal import HybridClock, Journal
from canopen_gateway.journal.clock import NANOS
from canopen_gateway.northbound.keys import emcy_key, prefix_of, state_key
from canopen_gateway.northbound.scaling import Scaling
from canopen_gateway.profiles.schema import Signal
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.threads import ThreadCount, ThreadRegistry
from canopen_gateway.zenoh_bridge.events import EventLog
from canopen_gateway.zenoh_bridge.history import HistoryService
from canopen_gateway.zenoh_bridge.housekeeping import housekeeping_loop, refresh
from canopen_gateway.zenoh_bridge.journaling import (
    ValueHistory,
    heard_entry,
    restore_seqs,
    value_keys_of,
)
from canopen_gateway.zenoh_bridge.pair import HeardSeq, seq_offset
from canopen_gateway.zenoh_bridge.payloads import pdo_json, value_json
from canopen_gateway.zenoh_bridge.plan import PdoPub, SignalPub, plan_publications, value_keys
from canopen_gateway.zenoh_bridge.queries import QueryService
from canopen_gateway.zenoh_bridge.sender import WITHHELD, ZenohSender
from canopen_gateway.zenoh_bridge.session import ZenohSession

log = logging.getLogger("gateway.zenoh")

ERROR_LOG_PERIOD_S = 10.0  # a failing publication is logged at most once per period and key


class _ValueBatch:
    """Report-by-exception values, published once per batch of frames, latest value first.

    The image's writer marks a signal as updated (a dict assignment under a lock) for every
    decoded PDO, and at the end of its batch (the image's batch listener: the CAN reader once
    it has handled every frame already received, the event loop after values read by SDO) the
    ``zenoh-publish`` thread publishes the *current* value of every marked signal (``flush``).
    While the reader or the publisher is behind, the marks of one signal coalesce into one
    sample: the work per batch is bounded by the number of signals, not by the number of
    frames, and subscribers always get the newest value. One wake-up per batch, none per
    value.

    No update is lost: the marks are taken under the lock they are made under, so a mark lands
    either in the batch being published or in the next one; and the value published is read
    after the mark was taken, so it is at least as new as the frame that marked it.
    """

    def __init__(
        self,
        offer: Callable[[NodeImage, SignalPub, float], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.offer = offer
        self.clock = clock
        self.lock = threading.Lock()
        self.pending: dict[int, tuple[NodeImage, SignalPub]] = {}
        self.errors = 0
        self._errlog = RateLimitedLog(log, ERROR_LOG_PERIOD_S)

    def mark(self, node: NodeImage, sp: SignalPub) -> None:
        """Mark a signal updated (the image's writer, for every decoded PDO)."""
        with self.lock:
            self.pending[id(sp)] = (node, sp)

    def mark_all(self, node: NodeImage, sps: tuple[Any, ...]) -> None:
        """Mark the publications of one PDO (one lock for all)."""
        with self.lock:
            pending = self.pending
            for sp in sps:
                pending[id(sp)] = (node, sp)

    def take(self) -> list[tuple[NodeImage, SignalPub]]:
        """The marked signals, unmarked (the next marks go to the next batch)."""
        with self.lock:
            batch, self.pending = self.pending, {}
        return list(batch.values())

    def flush(self) -> None:
        """End of the writer's batch: publish every marked signal's current value."""
        if not self.pending:
            return
        batch = self.take()
        now = self.clock()
        for node, sp in batch:
            try:
                self.offer(node, sp, now)
            except Exception as exc:  # noqa: BLE001 - a bad value must not stop publishing
                self.errors += 1
                self._errlog.warning(("publish", sp.key), "publishing %s failed: %r", sp.key, exc)


class ZenohBridge:
    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        commands: CommandService,
        catalog_fn: Callable[[], dict[str, Any]] | None = None,
        threads: ThreadRegistry | None = None,
    ):
        self.cfg = cfg
        self.image = image
        self.commands = commands
        self.catalog_fn = catalog_fn
        self.threads = threads if threads is not None else ThreadRegistry()
        self.prefix = prefix_of(cfg)
        #: what to publish, planned once (``plan.py``); the reader's work per frame is a
        #: lookup in ``_routes``
        plan = plan_publications(cfg, image, commands, self.prefix)
        self.pubs = plan.pubs
        self.by_node = plan.by_node
        self.pdo_pubs = plan.pdo_pubs
        self.pdo_by_node = plan.pdo_by_node
        self._routes = plan.routes
        #: raw PDOs published: the reader thread (TPDOs) and the loop (RPDOs) count each in
        #: its own cell; values are counted by their policies, under each signal's lock
        self._raw_publications = ThreadCount()
        #: the bridge's monotonic clock (injectable): publication policy, retries, waits
        self.clock: Callable[[], float] = time.monotonic
        self._values = _ValueBatch(self.offer, lambda: self.clock())
        #: the publishing threads (``sender.py``): ``zenoh-publish`` the values (a flush at
        #: most, and while marks keep coming at least, every ``zenoh.batch_ms``),
        #: ``zenoh-events`` the events (BLOCK: a congested link must not hold values back)
        self._sender = ZenohSender(
            self.threads, "zenoh-publish", self._values.flush, batch_s=cfg.zenoh.batch_ms / 1000.0
        )
        #: the id of this gateway's timestamps, and their clock (``journal.HybridClock``: the
        #: journal's once there is one): events and the journal are stamped without a session
        #: (the session's too, ``zid``: ``zenoh.json5`` ``id``, else a random one of 16 bytes)
        self.zid = str(cfg.zenoh.json5.get("id") or "1" + os.urandom(16).hex()[1:]).lower()
        self.stamp_id = bytes.fromhex(self.zid.rjust(len(self.zid) + len(self.zid) % 2, "0"))[::-1]
        self.hlc = HybridClock()
        self._events = ZenohSender(
            self.threads, "zenoh-events", pub_of=self._event_pub, timestamp=self.timestamp
        )
        #: the store and forward journal (``use_journal``): events and values are journaled
        #: whether a session is open or not, events published once committed (200 ms at most)
        self.journal: Journal | None = None
        #: a hot-standby pair (``pair.py``): this gateway's (master node id, pair node id),
        #: whether it publishes (it masters the bus), the seq heard of the other one
        self.member: tuple[int, int] | None = next(  # a pair per network: the first one's
            ((v.master.node_id, red.node_id) for v in cfg.network_views()
             if (red := v.master.redundancy) is not None), None,
        )  # fmt: skip
        self.publishing = True
        #: a pair per network: the nodes of the networks it stands by on while it masters another
        self.silent: frozenset[str] = frozenset()
        self.event_keys = {
            k(self.prefix, n): (k, n) for n in image.nodes for k in (state_key, emcy_key)
        }
        self.heard = HeardSeq(
            [*(sp.key for sp in self.pubs.values()), *(pp.key for pp in self.pdo_pubs.values())]
            + list(self.event_keys)
        )
        #: state and EMCY events: seq, stamp, journal, publication (``events.py``)
        self.events = EventLog(self.prefix, self._events, self.heard, self.hlc)
        #: the value keys the journal keeps a history of (``journaling.py``)
        self.value_history = value_keys_of(self.prefix, self.by_node, self.pdo_pubs)
        self.queries = QueryService(
            cfg,
            image,
            commands,
            self.prefix,
            session=lambda: self.session,
            scaling=self.scaling,
            value_keys=value_keys(plan, self.prefix),
            catalog_fn=catalog_fn,
            seq_of=self.seq_of,
        )
        #: the session, its publishers, tokens and tasks, from open to stop (``session.py``)
        self.link = ZenohSession(self, clock=lambda: self.clock())

    # ------------------------------------------------------------------ lifecycle (session.py)
    @property
    def session(self) -> zenoh.Session | None:
        """The open session, its publications declared; None before and after."""
        return self.link.session

    @property
    def up(self) -> bool:
        return self.link.up

    async def open(self) -> None:
        """Open the session, checked against a gateway of the same prefix (``ZenohSession.open``)."""
        await self.link.open()

    async def start(self) -> None:
        await self.link.start()

    async def stop(self) -> None:
        await self.link.stop()

    def attach(self) -> None:
        """The session starts: listen to the image, start the publishing threads."""
        self.image.value_listeners.append(self._on_values)
        self.image.batch_listeners.append(self._sender.wake_values)
        self.image.health_listeners.append(self._on_health)
        self._sender.start()
        self._events.start()
        self.queries.start(self.threads)

    async def detach(self) -> None:
        """The session stops: no more listening; marked values and queued events go out first."""
        if self._on_values in self.image.value_listeners:
            self.image.value_listeners.remove(self._on_values)
        if self._on_health in self.image.health_listeners:
            self.image.health_listeners.remove(self._on_health)
        if self._sender.wake_values in self.image.batch_listeners:
            self.image.batch_listeners.remove(self._sender.wake_values)
        if self.on_pdo in self.image.pdo_listeners:
            self.image.pdo_listeners.remove(self.on_pdo)
        await asyncio.to_thread(self.queries.stop)  # queries left are answered busy
        await asyncio.to_thread(self._sender.stop)  # marked values go out before the close
        await asyncio.to_thread(self._events.stop)  # and queued events

    async def housekeeping(self) -> None:
        """The periodic refresh (``housekeeping.py``), until cancelled."""
        await housekeeping_loop(self)

    def publishes(self, node: str) -> bool:
        """Whether this gateway publishes (and journals from its image) the node's samples: it
        masters the node's network (in a pair, the other member's are heard and journaled)."""
        return self.publishing and node not in self.silent

    def node_alive(self, node: NodeImage) -> bool:
        """Whether the node's token is wanted: its values usable and this gateway publishing."""
        return node.usable() and self.publishes(node.name)

    # ------------------------------------------------------------------ the journal
    def use_journal(self, journal: Journal) -> None:
        """Journal what the gateway hears and publishes (before the session starts): events
        are journaled as they happen and published once committed (``events.py``), the writer
        takes the values each ``values_ms`` from the image (``journaling.py``); every key's
        ``seq`` goes on above the highest the journal ever handed out."""
        self.journal = journal
        self.hlc = journal.hlc
        self.events.use_journal(journal, self.event_keys)
        self._events.journal_wait = journal.wait
        self._events.on_unjournaled = journal.note_unjournaled
        restore_seqs(journal.last_seqs(), self.value_history)
        history = ValueHistory(self.image, self.value_history, self.publishes, lambda: self.hlc)
        journal.values_from(history.window)
        self.queries.history = HistoryService(
            journal,
            self.prefix,
            [*self.event_keys, *(vk.key for vk in self.value_history)],
            self.stamp_id,
        )

    def on_heard(self, key: str, payload: bytes, timestamp: Any) -> None:
        """A sample of our prefix heard while standing by (a zenoh thread): its seq is kept
        (``HeardSeq``) and, with a journal, journaled as the other member published it, so
        this member's history covers the time before a take-over."""
        if self.silent and key.removeprefix(self.prefix + "/").split("/", 1)[0] not in self.silent:
            return  # its own sample: it masters this node's network (a pair per network)
        before = self.events.before_heard(key)
        self.heard.on_sample(key, payload)
        j = self.journal
        if j is None:
            return
        e = heard_entry(self.prefix, self.heard.keys, key, payload, timestamp, before)
        if e is not None and e.kind == "value":
            j.value(e)
        elif e is not None:
            j.append(e)

    def timestamp(self, ns: int) -> zenoh.Timestamp:
        """The Zenoh timestamp of a stamp (``hlc``) with this gateway's id."""
        return zenoh.Timestamp(zenoh.NTP64(ns // NANOS, ns % NANOS), self.stamp_id)

    def _event_pub(self, key: str) -> Any:
        """The publisher of an event key (``zenoh-events``): None while no session is open,
        ``WITHHELD`` while this gateway does not publish its node (a pair's other member does)."""
        if self.link.session is None:
            return None
        kind, node = self.event_keys[key]
        if not self.publishes(node):
            return WITHHELD
        pubs = self.link.state_pubs if kind is state_key else self.link.emcy_pubs
        return pubs.get(node)

    def events_ready(self) -> None:
        """The session's publishers are declared: events kept meanwhile go out."""
        self._events.resend()

    # ------------------------------------------------------------------ a hot-standby pair
    def set_mastering(self, mastering: bool, silent: frozenset[str] = frozenset()) -> None:
        """This gateway started or stopped mastering the bus (event loop; the app calls it at
        construction and at every role change of a pair). Standing by, it stops publishing
        and hears what the other one publishes; taking over, each key goes on above the
        highest seq heard (``pair.py``), then it publishes again, but the ``silent`` nodes."""
        silent = silent if mastering else frozenset()  # standing by on all: none publishes
        if mastering == self.publishing and silent == self.silent:
            return
        taken = self.silent - silent if self.publishing else frozenset(self.image.nodes) - silent
        if mastering:
            for node in (self.image.nodes[name] for name in taken):
                for sp in self.by_node.get(node.name, ()):
                    with sp.lock:
                        own = node.signals[sp.sig.name].seq
                        sp.seq_offset = seq_offset(sp.seq_offset, self.heard.get(sp.key), own)
                for pp in self.pdo_by_node.get(node.name, ()):
                    with pp.lock:
                        r = node.records.get(pp.names)
                        own = r[3] if r is not None else 0
                        pp.seq_offset = seq_offset(pp.seq_offset, self.heard.get(pp.key), own)
        self.publishing, self.silent = mastering, silent
        s = self.session
        if s is not None:
            self.link.declare_pair(s)
            for node in self.image.nodes.values():
                self._sync_token(node)

    def seq_of(self, node: str, name: str, own: int) -> int:
        """The seq a value key shows for the image's ``own``: with the offset of a take-over;
        while this gateway does not publish, never below what the other one published (its
        get answers go on from the published numbers too)."""
        sp = self.pubs.get((node, name))
        if sp is None:
            return own
        if self.publishes(node):
            return own + sp.seq_offset
        return max(own + sp.seq_offset, self.heard.get(sp.key))

    # ------------------------------------------------------------------ what to publish
    def scaling(self, node: str, sig: Signal) -> Scaling:
        sp = self.pubs.get((node, sig.name))
        if sp is not None:
            return sp.scaling
        return Scaling.of(sig, self.commands.node(node).cfg.signals.get(sig.name))

    def on_pdo(self, node: NodeImage, cob_id: int, data: bytes) -> None:
        """A PDO's raw bytes (the image's PDO listener, with ``zenoh.raw_pdo``)."""
        s = self.link.session  # per frame: no property call
        pub = self.link.raw_pubs.get((node.name, cob_id))
        if s is None or pub is None or not self.publishing or node.name in self.silent:
            return
        try:
            pub.put(data, timestamp=s.new_timestamp())
            self._raw_publications.add()
        except zenoh.ZError:
            pass

    # ------------------------------------------------------------------ values
    def offer(self, node: NodeImage, sp: SignalPub, now: float) -> None:
        """Publish the signal's current value if its policy says so (any thread: the reader's
        burst and the event loop may flush at the same time). Value and quality are read
        under the signal's lock, so a publication carries the latest value at its turn; one
        older than the last published (a lower ``seq``) is never published after it."""
        if type(sp) is PdoPub:  # a PDO marked in the batch (``publish: pdo``)
            return self.offer_pdo(node, sp, now)
        s = self.link.session
        if s is None or sp.pub is None or not self.publishing or node.name in self.silent:
            return
        with sp.lock:
            sv = node.signals[sp.sig.name]
            if sv.seq < sp.last_seq:
                return
            quality = node.quality(sv, now)
            value = sv.value
            if not sp.policy.offer(value, quality, now):
                return
            out = sv if not sp.seq_offset else sv._replace(seq=sv.seq + sp.seq_offset)
            payload = value_json(sp.sig, out, quality, sp.scaling)
            stamp = s.new_timestamp()
            try:
                sp.pub.put(payload, timestamp=stamp)
            except zenoh.ZError:
                return
            sp.last_pub = (out.seq, payload)  # the journal's value history may keep it
            sp.policy.published(value, quality, now)  # counts it, under the lock
            sp.last_seq = sv.seq

    def offer_pdo(self, node: NodeImage, pp: PdoPub, now: float, again: bool = False) -> None:
        """Publish the PDO's current record with all its signals, if it is newer than the last
        one published, or (``again``) its qualities changed since. Any thread, under the PDO's
        lock: one record read once, so the signals of a sample are of one frame."""
        s = self.link.session
        if s is None or pp.pub is None or not self.publishing or node.name in self.silent:
            return
        with pp.lock:
            r = node.records.get(pp.names)
            if r is None or r[3] < pp.last_seq or (r[3] == pp.last_seq and not again):
                return
            values, ts, mono, seq = r
            quality = node.quality
            entries = []
            for sig, i, sc in pp.entries:
                sv = SignalValue(sig.name, values[i], ts, mono, seq)
                entries.append((sig, sv, quality(sv, now), sc))
            qualities = tuple(e[2] for e in entries)
            if again and r[3] == pp.last_seq and qualities == pp.last_quality:
                return
            try:
                out = pdo_json(entries, ts, seq + pp.seq_offset)
                pp.pub.put(out, timestamp=s.new_timestamp())
            except zenoh.ZError:
                return
            pp.last_seq, pp.last_quality = seq, qualities
            pp.count += 1

    def _on_values(self, node: NodeImage, names: tuple[str, ...], ts: float) -> None:
        """Called on the bus reader thread for every decoded PDO."""
        if self.link.session is None or not self.publishing or node.name in self.silent:
            return
        route = self._routes.get((node.name, names))
        if route is not None:  # a TPDO's record: what to mark and publish, planned
            marks, every = route
            if marks:
                self._values.mark_all(node, marks)
            if every:
                now = self.clock()
                for sp in every:
                    self.offer(node, sp, now)
            return
        pubs = self.pubs
        nname = node.name
        mark = self._values.mark
        now = 0.0
        for name in names:
            sp = pubs.get((nname, name))
            if sp is None:
                continue
            if sp.policy.mode == "every":
                now = now or self.clock()
                self.offer(node, sp, now)
            else:
                mark(node, sp)

    # ------------------------------------------------------------------ events
    def _on_health(self, node: NodeImage, what: str) -> None:
        """Called on the event loop when a node's health changes or an EMCY arrives: the
        event is journaled and published (``events.py``) whether a session is open or not."""
        if not self.publishes(node.name):
            return
        self.events.on_health(node, what)
        self._sync_token(node)
        refresh(self, node, self.clock())

    def _sync_token(self, node: NodeImage) -> None:
        """A token while the node's values are usable: operational, guarding-bit link OK."""
        self.link.sync_token(node.name, self.node_alive(node))

    @property
    def publications(self) -> int:
        """Samples published: values (each signal's count, kept under its lock, whichever
        thread published) and raw PDOs (per thread), summed when read."""
        values = sum(sp.policy.published_count for sp in list(self.pubs.values()))
        pdos = sum(pp.count for pp in list(self.pdo_pubs.values()))
        return values + pdos + self._raw_publications.value

    @property
    def events_sent(self) -> int:
        return self._events.sent

    # ------------------------------------------------------------------ queries (queries.py)
    @property
    def refused(self) -> dict[str, int]:
        """Refused Zenoh writes by operation (``zenoh_refused_total{operation}``)."""
        return self.queries.refused

    async def dispatch(self, key: str, payload: bytes | None, type_param: str | None = None) -> Any:
        """Answer one concrete query key (see ``QueryService.dispatch``)."""
        return await self.queries.dispatch(key, payload, type_param)

    def snapshot(self, node: NodeImage) -> dict[str, Any]:
        return self.queries.snapshot(node)

    def catalog(self) -> dict[str, Any]:
        return self.queries.catalog()
