"""Zenoh bridge: owns the session; publishes the process image, node state and EMCY events, raw
PDOs on request, liveliness tokens per usable node and for the gateway, and declares the
queryable whose answers live in ``queries.py`` (``QueryService``).

Threads (started through the gateway's ``ThreadRegistry``: a thread that dies is reported and
turns /healthz not-ready, never silently):

* values are marked on the CAN reader thread right after the image was written, and the reader
  publishes the *current* value of every marked signal once per burst of frames, when it has
  handled every frame already received (the image's batch listener; coalescing when it is
  behind); ``publish: every`` signals are published by the reader for every frame; a signal's
  value, quality and policy are read and written under its own lock, whichever thread
  publishes, and a sample never follows a newer one; publications are counted per signal under
  that lock (raw PDOs per thread, ``threads.ThreadCount``) and summed when read;
* events (state, EMCY) are computed on the event loop when the master reports them and put by
  the ``zenoh-events`` thread in order, with congestion control BLOCK and priority
  INTERACTIVE_HIGH: never dropped, and a congested network never blocks the event loop;
* a housekeeping task on the event loop publishes held-back samples (max rate) and quality
  changes that no frame announces (stale by age);
* query callbacks run on zenoh threads and only hand the query to the event loop, where
  ``QueryService`` answers it through the command service and finalises it.

Values and events go out through zenoh-ext advanced publishers (``zenoh.history``): each keeps
the last samples of its key (1,000 per event key, the last value per value key by default),
sends heartbeats with its last sequence number and announces itself, so an
``AdvancedSubscriber`` with history and recovery gets what it missed while a router or a WAN
link was down. Our payloads carry their own ``seq`` too, so a plain subscriber sees a gap.

Writes (``set``, SDO download, ``nmt``) pass ``zenoh.writes`` / ``zenoh.write_allow`` first
(``access.WriteGate``, in ``queries.py``); a refused one is answered ``forbidden``, counted and
logged (rate-limited), and nothing goes on the bus.

The session is opened before the bus (``open``): when a gateway with the same prefix is
already announced on the Zenoh network (its ``<prefix>/alive/_gateway`` token), ``open``
raises ``PrefixInUse`` and the gateway does not start. In client mode, with no router
reachable, the gateway starts anyway and the bridge retries in the background (attempts start
0.5 s, 1 s, 2 s, then every 5 s apart). After a router restart zenoh reconnects by itself and
re-declares publishers, queryable and liveliness tokens.

Imports: zenoh, commands, image, config, ratelimit, threads, profiles.schema, northbound.keys,
northbound.scaling, zenoh_bridge.*. Never modbus/ (the catalogue gets Modbus addresses through a function passed in
by the app) and nothing of bus/ (nodes are known through the command service).
"""

from __future__ import annotations

import asyncio
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
import zenoh.ext

from gateway.commands import CommandService
from gateway.config import Config
from gateway.image import NodeImage, ProcessImage, SignalValue
from gateway.northbound.keys import (
    GATEWAY_TOKEN,
    alive_key,
    emcy_key,
    is_published,
    pdo_key,
    prefix_of,
    state_key,
    tpdo_key,
    value_key,
)
from gateway.northbound.scaling import Scaling
from gateway.profiles.schema import Signal
from gateway.ratelimit import RateLimitedLog
from gateway.threads import ThreadCount, ThreadRegistry
from gateway.zenoh_bridge.payloads import (
    emcy_payload,
    pdo_json,
    state_fingerprint,
    state_payload,
    value_json,
)
from gateway.zenoh_bridge.policy import ReportPolicy
from gateway.zenoh_bridge.queries import QueryService

log = logging.getLogger("gateway.zenoh")

JSON = zenoh.Encoding.APPLICATION_JSON
OCTETS = zenoh.Encoding.APPLICATION_OCTET_STREAM

#: config keys of ``zenoh.tls`` -> zenoh's ``transport/link/tls/<key>``
TLS_KEYS = (
    "root_ca_certificate",
    "listen_certificate",
    "listen_private_key",
    "connect_certificate",
    "connect_private_key",
    "enable_mtls",
    "verify_name_on_connect",
)

ERROR_LOG_PERIOD_S = 10.0  # a failing publication is logged at most once per period and key
CLIENT_CONNECT_TIMEOUT_MS = 1000  # one attempt to reach a router in client mode
#: time between the starts of two attempts to open a client session (the last one repeats)
REOPEN_SCHEDULE_S = (0.5, 1.0, 2.0, 5.0)
HOUSEKEEPING_PERIOD_S = 0.1
#: how long ``open`` waits for a connection to a configured router before asking it whether
#: our prefix is taken (peer mode connects in the background)
CONNECT_WAIT_S = 2.0
#: how long the liveliness get of the duplicate check may take
DUPLICATE_CHECK_TIMEOUT_S = 2.0


class PrefixInUse(RuntimeError):
    """Another gateway is announced under our prefix: two gateways must not share one."""


def zenoh_config(cfg: Config) -> zenoh.Config:
    """The session configuration: our keys first, then ``zenoh.json5`` (raw keys) on top."""
    z = cfg.zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(z.mode))
    if z.mode == "peer":  # a client does not listen
        conf.insert_json5("listen/endpoints", json.dumps(z.listen))
    conf.insert_json5("connect/endpoints", json.dumps(z.connect))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(z.multicast_scouting))
    if z.mode == "client":
        conf.insert_json5("connect/timeout_ms", json.dumps(CLIENT_CONNECT_TIMEOUT_MS))
    if z.tls is not None:
        for key in TLS_KEYS:
            value = getattr(z.tls, key)
            if isinstance(value, str):  # a file: relative to the config file
                value = str(cfg.base_dir / value)
            if value is not None:
                conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    if z.auth is not None:
        a = z.auth
        if a.user is not None:
            password = a.password
            if a.password_file is not None:
                password = (cfg.base_dir / a.password_file).read_text(encoding="utf-8").strip()
            conf.insert_json5("transport/auth/usrpwd/user", json.dumps(a.user))
            conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
        if a.dictionary_file is not None:
            conf.insert_json5(
                "transport/auth/usrpwd/dictionary_file",
                json.dumps(str(cfg.base_dir / a.dictionary_file)),
            )
    if z.access_control is not None:
        conf.insert_json5("access_control", json.dumps(z.access_control))
    for key, value in z.json5.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def _close_opened(fut: asyncio.Future[Any]) -> None:
    if not fut.cancelled() and fut.exception() is None:
        fut.result().close()


class _SignalPub:
    """One published signal: its key, engineering scaling, report policy and publisher."""

    __slots__ = ("sig", "key", "scaling", "policy", "lock", "pub", "last_seq")

    def __init__(self, sig: Signal, key: str, scaling: Scaling, policy: ReportPolicy):
        self.sig = sig
        self.key = key
        self.scaling = scaling
        self.policy = policy
        self.lock = threading.Lock()
        self.pub: Any = None
        self.last_seq = 0  # seq of the last sample published


class _PdoPub:
    """One received PDO published as one sample (``publish: pdo``): the record key (the
    signals one frame carries), the signals published in it, its publisher, and what was last
    published (the record's ``seq`` and the qualities), kept under its own lock."""

    __slots__ = ("key", "names", "entries", "lock", "pub", "last_seq", "last_quality", "count")

    def __init__(
        self, key: str, names: tuple[str, ...], entries: list[tuple[Signal, int, Scaling]]
    ):
        self.key = key
        self.names = names  # the record key (``NodeImage.records``)
        self.entries = entries  # (signal, index in the record, scaling)
        self.lock = threading.Lock()
        self.pub: Any = None
        self.last_seq = 0
        self.last_quality: tuple[Any, ...] = ()
        self.count = 0  # samples published, under the lock


class _EventSender:
    """Puts events in order on its own thread (BLOCK may wait; the event loop must not)."""

    def __init__(self, threads: ThreadRegistry) -> None:
        self.threads = threads
        self.queue: queue.SimpleQueue[tuple[Any, bytes, Any] | None] = queue.SimpleQueue()
        self.thread: threading.Thread | None = None
        self.sent = 0
        self.failed = 0

    def start(self) -> None:
        self.thread = self.threads.start("zenoh-events", self._run)

    def put(self, pub: Any, payload: bytes, timestamp: Any) -> None:
        self.queue.put((pub, payload, timestamp))

    def stop(self, timeout_s: float = 2.0) -> None:
        if self.thread is None:
            return
        self.queue.put(None)
        self.thread.join(timeout_s)
        self.thread = None

    def _run(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            pub, payload, ts = item
            try:
                pub.put(payload, timestamp=ts)
                self.sent += 1
            except Exception as exc:  # noqa: BLE001 - one failed put must not stop the events
                self.failed += 1
                log.warning("zenoh event publication failed: %r", exc)


class _ValueBatch:
    """Report-by-exception values, published once per batch of frames, latest value first.

    The image's writer marks a signal as updated (a dict assignment under a lock) for every
    decoded PDO, and at the end of its batch (the image's batch listener: the CAN reader once
    it has handled every frame already received, the event loop after values read by SDO) it
    publishes the *current* value of every marked signal on its own thread. While the reader is
    behind, its bursts grow and the marks of one signal coalesce into one sample: the work per
    batch is bounded by the number of signals, not by the number of frames, and subscribers
    always get the newest value. No thread hand-off, no wake-up per value.

    No update is lost: the marks are taken under the lock they are made under, so a mark lands
    either in the batch being published or in the next one; and the value published is read
    after the mark was taken, so it is at least as new as the frame that marked it.
    """

    def __init__(
        self,
        offer: Callable[[NodeImage, _SignalPub, float], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.offer = offer
        self.clock = clock
        self.lock = threading.Lock()
        self.pending: dict[int, tuple[NodeImage, _SignalPub]] = {}
        self.errors = 0
        self._errlog = RateLimitedLog(log, ERROR_LOG_PERIOD_S)

    def mark(self, node: NodeImage, sp: _SignalPub) -> None:
        """Mark a signal updated (the image's writer, for every decoded PDO)."""
        with self.lock:
            self.pending[id(sp)] = (node, sp)

    def mark_all(self, node: NodeImage, sps: tuple[Any, ...]) -> None:
        """Mark the publications of one PDO (one lock for all)."""
        with self.lock:
            pending = self.pending
            for sp in sps:
                pending[id(sp)] = (node, sp)

    def take(self) -> list[tuple[NodeImage, _SignalPub]]:
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
        self.session: zenoh.Session | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.pubs: dict[tuple[str, str], _SignalPub] = {}
        self.by_node: dict[str, list[_SignalPub]] = {}
        #: ``publish: pdo``: (node, record key) -> its PDO publication
        self.pdo_pubs: dict[tuple[str, tuple[str, ...]], _PdoPub] = {}
        self.pdo_by_node: dict[str, list[_PdoPub]] = {}
        #: (node, record key of a TPDO) -> (publications to mark, ``publish: every`` signals):
        #: the reader's work per frame, planned once
        self._routes: dict[
            tuple[str, tuple[str, ...]], tuple[tuple[Any, ...], tuple[Any, ...]]
        ] = {}
        self.state_pubs: dict[str, Any] = {}
        self.emcy_pubs: dict[str, Any] = {}
        self.raw_pubs: dict[tuple[str, int], Any] = {}
        self.tokens: dict[str, Any] = {}
        self.queryable: Any = None
        #: raw PDOs published: the reader thread (TPDOs) and the loop (RPDOs) count each in
        #: its own cell; values are counted by their policies, under each signal's lock
        self._raw_publications = ThreadCount()
        self.up = False
        self._events = _EventSender(self.threads)
        self._values = _ValueBatch(self._offer, lambda: self._clock())
        self._last_state: dict[str, tuple[Any, ...]] = {}
        self._event_seq: dict[str, int] = {}
        self._opened: zenoh.Session | None = None  # open, checked, not declared yet
        self._open_failed: zenoh.ZError | None = None
        self._last_attempt_s = 0.0
        #: the bridge's monotonic clock (injectable): publication policy, retries, waits
        self._clock: Callable[[], float] = time.monotonic
        self._sleep: Callable[[float], Any] = asyncio.sleep
        self._tasks: list[asyncio.Task[Any]] = []
        self._plan()
        self.queries = QueryService(
            cfg,
            image,
            commands,
            self.prefix,
            session=lambda: self.session,
            scaling=self.scaling,
            value_keys=self._value_keys(),
            catalog_fn=catalog_fn,
        )

    # ------------------------------------------------------------------ what to publish
    def _plan(self) -> None:
        default_mode = self.cfg.zenoh.publish
        for name in self.image.nodes:
            rt = self.commands.node(name)
            sps: list[_SignalPub] = []
            in_pdo: dict[str, tuple[Signal, Scaling]] = {}
            for sig in rt.lp.profile.signals:
                if not is_published(sig):
                    continue
                ov = rt.cfg.signals.get(sig.name)
                mode = (ov.publish if ov is not None and ov.publish else None) or default_mode
                if mode == "off":
                    continue
                sc = Scaling.of(sig, ov)
                if mode == "pdo":
                    in_pdo[sig.name] = (sig, sc)
                    continue
                policy = ReportPolicy(
                    mode,
                    deadband=ov.deadband if ov is not None else 0.0,
                    scale=sc.scale,
                    max_rate_hz=ov.max_rate_hz if ov is not None else None,
                )
                sp = _SignalPub(sig, value_key(self.prefix, name, sig.name), sc, policy)
                self.pubs[(name, sig.name)] = sp
                sps.append(sp)
            self.by_node[name] = sps
            pps = []
            for number, names in rt.tpdo_records:
                entries = [
                    (in_pdo[n][0], i, in_pdo[n][1]) for i, n in enumerate(names) if n in in_pdo
                ]
                if entries:
                    pp = _PdoPub(tpdo_key(self.prefix, name, number), names, entries)
                    self.pdo_pubs[(name, names)] = pp
                    pps.append(pp)
            self.pdo_by_node[name] = pps
            for _number, names in rt.tpdo_records:
                pdo_pub = self.pdo_pubs.get((name, names))
                sps_of = [self.pubs[(name, n)] for n in names if (name, n) in self.pubs]
                every = tuple(sp for sp in sps_of if sp.policy.mode == "every")
                marks = tuple(sp for sp in sps_of if sp.policy.mode != "every")
                self._routes[(name, names)] = (
                    (pdo_pub, *marks) if pdo_pub is not None else marks, every
                )

    def _value_keys(self) -> dict[str, list[tuple[str, Signal]]]:
        """Per node, the value keys a get answers from the image: every published signal's,
        whether its samples go out on its value key or in its PDO's sample."""
        out: dict[str, list[tuple[str, Signal]]] = {}
        for name, sps in self.by_node.items():
            keys = [(sp.key, sp.sig) for sp in sps]
            for pp in self.pdo_by_node.get(name, ()):
                keys += [
                    (value_key(self.prefix, name, sig.name), sig) for sig, _i, _sc in pp.entries
                ]
            out[name] = keys
        return out

    def scaling(self, node: str, sig: Signal) -> Scaling:
        sp = self.pubs.get((node, sig.name))
        if sp is not None:
            return sp.scaling
        return Scaling.of(sig, self.commands.node(node).cfg.signals.get(sig.name))

    # ------------------------------------------------------------------ lifecycle
    async def open(self) -> None:
        """Open the session and make sure no other gateway runs under our prefix; called by the
        app before the bus starts. Raises ``PrefixInUse`` (the session is closed then) or, in
        peer mode, zenoh.ZError when the session cannot be opened at all."""
        self.loop = self.queries.loop = asyncio.get_running_loop()
        conf = zenoh_config(self.cfg)  # a bad config raises here, before anything runs
        self._last_attempt_s = self._clock()
        try:
            self._opened = await self._open_checked(conf)
        except zenoh.ZError as exc:
            if self.cfg.zenoh.mode != "client":
                raise
            self._open_failed = exc

    async def start(self) -> None:
        if self.loop is None:
            await self.open()
        self.image.value_listeners.append(self._on_values)
        self.image.batch_listeners.append(self._values.flush)
        self.image.health_listeners.append(self._on_health)
        self._events.start()
        opened, self._opened = self._opened, None
        if opened is not None:
            try:
                self._declare(opened)
            except zenoh.ZError:
                await asyncio.to_thread(opened.close)
                await self.stop()
                raise
            log.info(
                "Zenoh session %s open (%s), prefix %s",
                opened.zid(),
                self.cfg.zenoh.mode,
                self.prefix,
            )
        else:
            log.warning(
                "no Zenoh router reachable (%s); retrying in the background", self._open_failed
            )
            self._tasks.append(asyncio.create_task(self._reopen(), name="zenoh-open"))
        self._tasks.append(asyncio.create_task(self._housekeeping(), name="zenoh-housekeeping"))

    async def _open_checked(self, conf: zenoh.Config) -> zenoh.Session:
        """A new session, once no other gateway is announced under our prefix."""
        opening = asyncio.get_running_loop().run_in_executor(None, zenoh.open, conf)
        try:
            session = await asyncio.shield(opening)
        except asyncio.CancelledError:  # stopped while opening: close what the thread opens
            opening.add_done_callback(_close_opened)
            raise
        try:
            if self.cfg.zenoh.refuse_duplicate_prefix:
                other = await asyncio.to_thread(self._other_gateway, session)
                if other:
                    raise PrefixInUse(
                        f"another gateway already runs under Zenoh prefix {self.prefix} "
                        f"(token {other} is present): give this gateway its own gateway.name "
                        "or zenoh.prefix, or stop the other one"
                    )
        except BaseException:
            await asyncio.to_thread(session.close)
            raise
        return session

    def _other_gateway(self, session: zenoh.Session) -> str | None:
        """Worker thread: the key of a gateway token under our prefix, if one is announced."""
        z = self.cfg.zenoh
        if z.connect:  # wait (bounded) for the configured router(s) to be connected
            deadline = self._clock() + CONNECT_WAIT_S
            while self._clock() < deadline:
                info = session.info
                if list(info.routers_zid()) or list(info.peers_zid()):
                    break
                time.sleep(0.02)
        key = alive_key(self.prefix, GATEWAY_TOKEN)
        for r in session.liveliness().get(key, timeout=DUPLICATE_CHECK_TIMEOUT_S):
            if r.ok is not None:
                return str(r.ok.key_expr)
        return None

    async def _reopen(self) -> None:
        """Client mode: open the session in the background; attempts *start* on the schedule
        (an attempt itself takes up to the connect timeout)."""
        attempt = 0
        while self.session is None:
            period = REOPEN_SCHEDULE_S[min(attempt, len(REOPEN_SCHEDULE_S) - 1)]
            await self._sleep(max(0.0, self._last_attempt_s + period - self._clock()))
            attempt += 1
            self._last_attempt_s = self._clock()
            try:
                session = await self._try_open()
            except zenoh.ZError as exc:
                if attempt in (1, 10) or attempt % 60 == 0:
                    log.warning(
                        "Zenoh router still unreachable after %d attempts: %s", attempt, exc
                    )
                continue
            except PrefixInUse as exc:
                if attempt in (1, 10) or attempt % 60 == 0:
                    log.error("%s; retrying", exc)
                continue
            try:
                self._declare(session)
            except zenoh.ZError as exc:
                log.warning("Zenoh declarations failed: %s", exc)
                await asyncio.to_thread(session.close)
                continue
            log.info("Zenoh session %s open (client), prefix %s", session.zid(), self.prefix)

    async def _try_open(self) -> zenoh.Session:
        return await self._open_checked(zenoh_config(self.cfg))

    def _publisher(self, s: zenoh.Session, key: str, cache: int, **qos: Any) -> Any:
        """An advanced publisher (cache, miss detection, publisher detection), or a plain one
        when the cache size is 0."""
        if cache <= 0:
            return s.declare_publisher(key, encoding=JSON, **qos)
        hb_ms = self.cfg.zenoh.history.heartbeat_ms
        return zenoh.ext.declare_advanced_publisher(
            s,
            key,
            encoding=JSON,
            cache=zenoh.ext.CacheConfig(cache),
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=hb_ms / 1000.0, sporadic_heartbeat=None)
            if hb_ms
            else None,
            publisher_detection=True,
            **qos,
        )

    def _declare(self, s: zenoh.Session) -> None:
        hist = self.cfg.zenoh.history
        for sp in self.pubs.values():
            sp.pub = self._publisher(
                s, sp.key, hist.values, congestion_control=zenoh.CongestionControl.DROP
            )
        for pp in self.pdo_pubs.values():
            pp.pub = self._publisher(
                s, pp.key, hist.values, congestion_control=zenoh.CongestionControl.DROP
            )
        for name in self.image.nodes:
            for pubs, key in ((self.state_pubs, state_key), (self.emcy_pubs, emcy_key)):
                pubs[name] = self._publisher(
                    s,
                    key(self.prefix, name),
                    hist.events,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.INTERACTIVE_HIGH,
                    reliability=zenoh.Reliability.RELIABLE,
                )
        if self.cfg.zenoh.raw_pdo:
            self._declare_raw_pdo(s)
        self.tokens[GATEWAY_TOKEN] = s.liveliness().declare_token(
            alive_key(self.prefix, GATEWAY_TOKEN)
        )
        self.queryable = s.declare_queryable(f"{self.prefix}/**", self.queries.on_query)
        self.session = s
        self.up = True
        for node in self.image.nodes.values():
            self._sync_token(node)

    def _declare_raw_pdo(self, s: zenoh.Session) -> None:
        """Raw bytes of every TPDO received and every RPDO sent, on ``<node>/pdo/<cob-id>``
        (the process image's PDO listeners: called on the reader thread for TPDOs)."""
        for name in self.image.nodes:
            rt = self.commands.node(name)
            for cob_id in rt.pdo_cob_ids:
                self.raw_pubs[(name, cob_id)] = s.declare_publisher(
                    pdo_key(self.prefix, name, cob_id),
                    encoding=OCTETS,
                    congestion_control=zenoh.CongestionControl.DROP,
                )
        self.image.pdo_listeners.append(self._on_pdo)

    def _on_pdo(self, node: NodeImage, cob_id: int, data: bytes) -> None:
        s = self.session
        pub = self.raw_pubs.get((node.name, cob_id))
        if s is None or pub is None:
            return
        try:
            pub.put(data, timestamp=s.new_timestamp())
            self._raw_publications.add()
        except zenoh.ZError:
            pass

    async def stop(self) -> None:
        self.up = False
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            try:
                await t
            except (asyncio.CancelledError, Exception):  # noqa: BLE001
                pass
        self._tasks.clear()
        if self._on_values in self.image.value_listeners:
            self.image.value_listeners.remove(self._on_values)
        if self._on_health in self.image.health_listeners:
            self.image.health_listeners.remove(self._on_health)
        if self._values.flush in self.image.batch_listeners:
            self.image.batch_listeners.remove(self._values.flush)
        if self._on_pdo in self.image.pdo_listeners:
            self.image.pdo_listeners.remove(self._on_pdo)
        await asyncio.to_thread(self._events.stop)  # queued events go out before the close
        s, self.session = self.session, None
        opened, self._opened = self._opened, None
        self.tokens.clear()
        for sess in (s, opened):
            if sess is not None:
                await asyncio.to_thread(sess.close)

    # ------------------------------------------------------------------ values
    def _offer(self, node: NodeImage, sp: _SignalPub, now: float) -> None:
        """Publish the signal's current value if its policy says so (any thread: the reader's
        burst and the event loop may flush at the same time). Value and quality are read
        under the signal's lock, so a publication carries the latest value at its turn; one
        older than the last published (a lower ``seq``) is never published after it."""
        if type(sp) is _PdoPub:  # a PDO marked in the batch (``publish: pdo``)
            return self._offer_pdo(node, sp, now)
        s = self.session
        if s is None or sp.pub is None:
            return
        with sp.lock:
            sv = node.signals[sp.sig.name]
            if sv.seq < sp.last_seq:
                return
            quality = node.quality(sv, now)
            value = sv.value
            if not sp.policy.offer(value, quality, now):
                return
            payload = value_json(sp.sig, sv, quality, sp.scaling)
            try:
                sp.pub.put(payload, timestamp=s.new_timestamp())
            except zenoh.ZError:
                return
            sp.policy.published(value, quality, now)  # counts it, under the lock
            sp.last_seq = sv.seq

    def _offer_pdo(self, node: NodeImage, pp: _PdoPub, now: float, again: bool = False) -> None:
        """Publish the PDO's current record with all its signals, if it is newer than the last
        one published, or (``again``) its qualities changed since. Any thread, under the PDO's
        lock: one record read once, so the signals of a sample are of one frame."""
        s = self.session
        if s is None or pp.pub is None:
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
                pp.pub.put(pdo_json(entries, ts, seq), timestamp=s.new_timestamp())
            except zenoh.ZError:
                return
            pp.last_seq, pp.last_quality = seq, qualities
            pp.count += 1

    def _on_values(self, node: NodeImage, names: tuple[str, ...], ts: float) -> None:
        """Called on the bus reader thread for every decoded PDO."""
        if self.session is None:
            return
        route = self._routes.get((node.name, names))
        if route is not None:  # a TPDO's record: what to mark and publish, planned
            marks, every = route
            if marks:
                self._values.mark_all(node, marks)
            if every:
                now = self._clock()
                for sp in every:
                    self._offer(node, sp, now)
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
                now = now or self._clock()
                self._offer(node, sp, now)
            else:
                mark(node, sp)

    def _refresh(self, node: NodeImage, now: float) -> None:
        """Held-back samples whose time has come, and quality changes without a new frame."""
        for pp in self.pdo_by_node.get(node.name, ()):
            if pp.last_seq:
                self._offer_pdo(node, pp, now, again=True)
        for sp in self.by_node.get(node.name, ()):
            sv = node.signals[sp.sig.name]
            if not sv.seq:
                continue
            pol = sp.policy
            with sp.lock:  # the policy is the publishing thread's, under the signal's lock
                due = pol.take_due(now) or (
                    pol.last_time_s is not None and node.quality(sv, now) != pol.last_quality
                )
            if due:
                self._offer(node, sp, now)

    async def _housekeeping(self) -> None:
        period = HOUSEKEEPING_PERIOD_S
        rates = [sp.policy.min_interval_s for sp in self.pubs.values() if sp.policy.min_interval_s]
        if rates:
            period = max(0.01, min(period, min(rates) / 2))
        while True:
            await asyncio.sleep(period)
            if self.session is None:
                continue
            now = self._clock()
            for node in self.image.nodes.values():
                self._refresh(node, now)

    # ------------------------------------------------------------------ events
    def _on_health(self, node: NodeImage, what: str) -> None:
        """Called on the event loop when a node's health changes or an EMCY arrives."""
        s = self.session
        if s is None:
            return
        if what == "emcy":
            rec = node.health.last_emcy
            if rec is not None:
                payload = emcy_payload(node, rec, node.health.emcy_count)
                self._put_event(
                    s, self.emcy_pubs[node.name], emcy_key(self.prefix, node.name), payload
                )
        else:
            d = state_payload(node)
            fp = state_fingerprint(d)
            if self._last_state.get(node.name) != fp:
                self._last_state[node.name] = fp
                self._put_event(s, self.state_pubs[node.name], state_key(self.prefix, node.name), d)
        self._sync_token(node)
        self._refresh(node, self._clock())

    def _put_event(self, s: zenoh.Session, pub: Any, key: str, payload: dict[str, Any]) -> None:
        """Queue an event with the next ``seq`` of its key (1, 2, 3... since the gateway
        started: a subscriber that sees a gap missed an event)."""
        seq = self._event_seq.get(key, 0) + 1
        self._event_seq[key] = seq
        payload["seq"] = seq
        self._events.put(pub, json.dumps(payload).encode(), s.new_timestamp())

    def _sync_token(self, node: NodeImage) -> None:
        """A token while the node's values are usable: operational, guarding-bit link OK."""
        s = self.session
        if s is None:
            return
        alive = node.usable()
        tok = self.tokens.get(node.name)
        if alive and tok is None:
            self.tokens[node.name] = s.liveliness().declare_token(alive_key(self.prefix, node.name))
        elif not alive and tok is not None:
            del self.tokens[node.name]
            try:
                tok.undeclare()
            except zenoh.ZError:
                pass

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
