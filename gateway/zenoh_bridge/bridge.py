"""Zenoh bridge: publishes the process image, node state and EMCY events, raw PDOs on request,
liveliness tokens per alive node and for the gateway, and answers queries through the command
service.

Threads:

* values are published on the CAN reader thread, right after the image was written (zenoh puts
  are thread-safe; congestion control DROP, so a slow network never blocks the reader);
* events (state, EMCY) are computed on the event loop when the master reports them and put by
  one sender thread in order, with congestion control BLOCK and priority INTERACTIVE_HIGH: they
  are never dropped and a congested network never blocks the event loop;
* a housekeeping task on the event loop publishes held-back samples (max rate) and quality
  changes that no frame announces (stale by age);
* query callbacks run on zenoh threads and only hand the query to the event loop, where the
  command service answers it and the query is finalised.

The session is opened at start; in client mode, with no router reachable, the gateway starts
anyway and the bridge keeps trying in the background. After a router restart zenoh reconnects
by itself and re-declares publishers, queryable and liveliness tokens.

Imports: zenoh, commands, errors, image, config, objref, profiles.schema, zenoh_bridge.*.
Never modbus/ (the catalogue gets Modbus addresses through a function passed in by the app).
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

from gateway.commands import CommandService
from gateway.config import Config
from gateway.errors import GatewayError
from gateway.image import NodeImage, ProcessImage
from gateway.profiles.schema import Signal
from gateway.zenoh_bridge.keys import (
    GATEWAY_TOKEN,
    Request,
    alive_key,
    catalog_key,
    emcy_key,
    has_wildcard,
    is_published,
    is_writable,
    nmt_key,
    parse_key,
    pdo_key,
    prefix_of,
    set_key,
    snapshot_key,
    state_key,
    value_key,
)
from gateway.zenoh_bridge.payloads import (
    Scaling,
    emcy_payload,
    engineering,
    error_payload,
    nmt_command,
    reply_value,
    sdo_write_body,
    set_body,
    set_many_body,
    state_fingerprint,
    state_payload,
    to_raw,
    value_json,
    value_payload,
)
from gateway.zenoh_bridge.policy import ReportPolicy

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

CLIENT_CONNECT_TIMEOUT_MS = 1000  # one attempt to reach a router in client mode
REOPEN_BACKOFF_S = (0.5, 1.0, 2.0, 5.0)
HOUSEKEEPING_PERIOD_S = 0.1


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
    for key, value in z.json5.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def _close_opened(fut: asyncio.Future[Any]) -> None:
    if not fut.cancelled() and fut.exception() is None:
        fut.result().close()


class _SignalPub:
    """One published signal: its key, engineering scaling, report policy and publisher."""

    __slots__ = ("sig", "key", "scaling", "policy", "lock", "pub")

    def __init__(self, sig: Signal, key: str, scaling: Scaling, policy: ReportPolicy):
        self.sig = sig
        self.key = key
        self.scaling = scaling
        self.policy = policy
        self.lock = threading.Lock()
        self.pub: Any = None


class _EventSender:
    """Puts events in order on its own thread (BLOCK may wait; the event loop must not)."""

    def __init__(self) -> None:
        self.queue: queue.SimpleQueue[tuple[Any, bytes, Any] | None] = queue.SimpleQueue()
        self.thread: threading.Thread | None = None
        self.sent = 0
        self.failed = 0

    def start(self) -> None:
        self.thread = threading.Thread(target=self._run, name="zenoh-events", daemon=True)
        self.thread.start()

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
            except zenoh.ZError as exc:
                self.failed += 1
                log.warning("zenoh event publication failed: %s", exc)


class _ValueSender:
    """Publishes report-by-exception values on its own thread, latest value first.

    The CAN reader only marks a signal as updated (a dict assignment); this thread publishes
    the signal's *current* value, so when frames arrive faster than JSON can be published the
    intermediate values are coalesced instead of queued. The reader thus keeps pace with the
    bus (heartbeats are never processed late because of publishing) and subscribers always get
    the newest value. Signals with ``publish: every`` are published by the reader itself.
    """

    def __init__(self, offer: Callable[[NodeImage, _SignalPub, float], None]) -> None:
        self.offer = offer
        self.pending: dict[int, tuple[NodeImage, _SignalPub]] = {}
        self.wake = threading.Event()
        self.running = False
        self.thread: threading.Thread | None = None

    def start(self) -> None:
        self.running = True
        self.thread = threading.Thread(target=self._run, name="zenoh-values", daemon=True)
        self.thread.start()

    def mark(self, node: NodeImage, sp: _SignalPub) -> None:
        self.pending[id(sp)] = (node, sp)
        self.wake.set()

    def stop(self, timeout_s: float = 2.0) -> None:
        self.running = False
        self.wake.set()
        if self.thread is not None:
            self.thread.join(timeout_s)
            self.thread = None

    def _run(self) -> None:
        while self.running:
            self.wake.wait(0.1)
            self.wake.clear()
            if not self.pending:
                continue
            batch, self.pending = self.pending, {}
            now = time.monotonic()
            for node, sp in batch.values():
                try:
                    self.offer(node, sp, now)
                except Exception:  # noqa: BLE001 - a bad value must not stop publishing
                    log.exception("publishing %s failed", sp.key)


class ZenohBridge:
    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        commands: CommandService,
        catalog_fn: Callable[[], dict[str, Any]] | None = None,
    ):
        self.cfg = cfg
        self.image = image
        self.commands = commands
        self.catalog_fn = catalog_fn
        self.prefix = prefix_of(cfg)
        self.session: zenoh.Session | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.pubs: dict[tuple[str, str], _SignalPub] = {}
        self.by_node: dict[str, list[_SignalPub]] = {}
        self.state_pubs: dict[str, Any] = {}
        self.emcy_pubs: dict[str, Any] = {}
        self.raw_pubs: dict[tuple[str, int], Any] = {}
        self.tokens: dict[str, Any] = {}
        self.queryable: Any = None
        self.publications = 0
        self.up = False
        self._events = _EventSender()
        self._values = _ValueSender(self._offer)
        self._last_state: dict[str, tuple[Any, ...]] = {}
        self._tasks: list[asyncio.Task[Any]] = []
        self._answers: set[asyncio.Future[Any]] = set()
        self._plan()

    # ------------------------------------------------------------------ what to publish
    def _plan(self) -> None:
        default_mode = self.cfg.zenoh.publish
        for name in self.image.nodes:
            rt = self.commands.node(name)
            sps: list[_SignalPub] = []
            for sig in rt.lp.profile.signals:
                if not is_published(sig):
                    continue
                ov = rt.cfg.signals.get(sig.name)
                mode = (ov.publish if ov is not None and ov.publish else None) or default_mode
                if mode == "off":
                    continue
                sc = Scaling.of(sig, ov)
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

    def scaling(self, node: str, sig: Signal) -> Scaling:
        sp = self.pubs.get((node, sig.name))
        if sp is not None:
            return sp.scaling
        return Scaling.of(sig, self.commands.node(node).cfg.signals.get(sig.name))

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        conf = zenoh_config(self.cfg)  # a bad config raises here, before anything runs
        self.image.value_listeners.append(self._on_values)
        self.image.health_listeners.append(self._on_health)
        self._events.start()
        self._values.start()
        try:
            await self._open(conf)
        except zenoh.ZError as exc:
            if self.cfg.zenoh.mode != "client":
                await self.stop()
                raise
            log.warning("no Zenoh router reachable (%s); retrying in the background", exc)
            self._tasks.append(asyncio.create_task(self._reopen(), name="zenoh-open"))
        self._tasks.append(asyncio.create_task(self._housekeeping(), name="zenoh-housekeeping"))

    async def _open(self, conf: zenoh.Config) -> None:
        opening = asyncio.get_running_loop().run_in_executor(None, zenoh.open, conf)
        try:
            session = await asyncio.shield(opening)
        except asyncio.CancelledError:  # stopped while opening: close what the thread opens
            opening.add_done_callback(_close_opened)
            raise
        try:
            self._declare(session)
        except zenoh.ZError:
            await asyncio.to_thread(session.close)
            raise
        log.info(
            "Zenoh session %s open (%s), prefix %s", session.zid(), self.cfg.zenoh.mode, self.prefix
        )

    async def _reopen(self) -> None:
        attempt = 0
        while self.session is None:
            await asyncio.sleep(REOPEN_BACKOFF_S[min(attempt, len(REOPEN_BACKOFF_S) - 1)])
            attempt += 1
            try:
                await self._open(zenoh_config(self.cfg))
            except zenoh.ZError as exc:
                if attempt in (1, 10) or attempt % 60 == 0:
                    log.warning(
                        "Zenoh router still unreachable after %d attempts: %s", attempt, exc
                    )

    def _declare(self, s: zenoh.Session) -> None:
        for sp in self.pubs.values():
            sp.pub = s.declare_publisher(
                sp.key, encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
            )
        for name in self.image.nodes:
            for pubs, key in ((self.state_pubs, state_key), (self.emcy_pubs, emcy_key)):
                pubs[name] = s.declare_publisher(
                    key(self.prefix, name),
                    encoding=JSON,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.INTERACTIVE_HIGH,
                    reliability=zenoh.Reliability.RELIABLE,
                )
        if self.cfg.zenoh.raw_pdo:
            self._declare_raw_pdo(s)
        self.tokens[GATEWAY_TOKEN] = s.liveliness().declare_token(
            alive_key(self.prefix, GATEWAY_TOKEN)
        )
        self.queryable = s.declare_queryable(f"{self.prefix}/**", self._on_query)
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
            self.publications += 1
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
        if self._on_pdo in self.image.pdo_listeners:
            self.image.pdo_listeners.remove(self._on_pdo)
        await asyncio.to_thread(self._values.stop)
        await asyncio.to_thread(self._events.stop)  # queued events go out before the close
        s, self.session = self.session, None
        self.tokens.clear()
        if s is not None:
            await asyncio.to_thread(s.close)

    # ------------------------------------------------------------------ values
    def _offer(self, node: NodeImage, sp: _SignalPub, now: float) -> None:
        """Publish the signal's current value if its policy says so (any thread)."""
        s = self.session
        if s is None or sp.pub is None:
            return
        sv = node.signals[sp.sig.name]
        quality = node.quality(sv, now)
        with sp.lock:
            value = sv.value
            if not sp.policy.offer(value, quality, now):
                return
            payload = value_json(sp.sig, sv, quality, sp.scaling)
            try:
                sp.pub.put(payload, timestamp=s.new_timestamp())
            except zenoh.ZError:
                return
            sp.policy.published(value, quality, now)
        self.publications += 1

    def _on_values(self, node: NodeImage, names: tuple[str, ...], ts: float) -> None:
        """Called on the bus reader thread for every decoded PDO."""
        if self.session is None:
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
                now = now or time.monotonic()
                self._offer(node, sp, now)
            else:
                mark(node, sp)

    def _refresh(self, node: NodeImage, now: float) -> None:
        """Held-back samples whose time has come, and quality changes without a new frame."""
        for sp in self.by_node.get(node.name, ()):
            sv = node.signals[sp.sig.name]
            if not sv.seq:
                continue
            pol = sp.policy
            if pol.take_due(now) or (
                pol.last_time_s is not None and node.quality(sv, now) != pol.last_quality
            ):
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
            now = time.monotonic()
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
                self._events.put(
                    self.emcy_pubs[node.name], json.dumps(payload).encode(), s.new_timestamp()
                )
        else:
            d = state_payload(node)
            fp = state_fingerprint(d)
            if self._last_state.get(node.name) != fp:
                self._last_state[node.name] = fp
                self._events.put(
                    self.state_pubs[node.name], json.dumps(d).encode(), s.new_timestamp()
                )
        self._sync_token(node)
        self._refresh(node, time.monotonic())

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
    def events_sent(self) -> int:
        return self._events.sent

    # ------------------------------------------------------------------ queries
    def _on_query(self, query: zenoh.Query) -> None:
        """Zenoh thread: hand over to the event loop; never block here."""
        loop = self.loop
        if loop is None or loop.is_closed() or self.session is None:
            query.drop()
            return
        try:
            loop.call_soon_threadsafe(self._spawn_answer, query)
        except RuntimeError:
            query.drop()

    def _spawn_answer(self, query: zenoh.Query) -> None:
        fut = asyncio.ensure_future(self._answer(query))
        self._answers.add(fut)
        fut.add_done_callback(self._answers.discard)

    def _reply(self, query: zenoh.Query, key: str, result: Any) -> None:
        s = self.session
        query.reply(
            key,
            json.dumps(result),
            encoding=JSON,
            timestamp=s.new_timestamp() if s is not None else None,
        )

    async def _answer(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        try:
            if has_wildcard(key):
                self._answer_wildcard(query, key)
                return
            payload = query.payload.to_bytes() if query.payload is not None else None
            type_param = query.parameters.get("type")
            result = await self.dispatch(key, payload, type_param)
            self._reply(query, key, result)
        except Exception as exc:  # noqa: BLE001 - nothing a client sends may crash the gateway
            if not isinstance(exc, (GatewayError, ValueError, KeyError, TypeError)):
                log.exception("zenoh query %s failed", key)
            try:
                query.reply_err(json.dumps(error_payload(exc, key)), encoding=JSON)
            except zenoh.ZError:
                pass
        finally:
            query.drop()

    def _answer_wildcard(self, query: zenoh.Query, key: str) -> None:
        """A key expression with wildcards gets the read-only answers it matches (catalogue,
        states, snapshots, latest values); commands and SDO never run on a wildcard."""
        ke = zenoh.KeyExpr(key)
        p = self.prefix
        if ke.intersects(catalog_key(p)):
            self._reply(query, catalog_key(p), self.catalog())
        for name, node in self.image.nodes.items():
            if ke.intersects(state_key(p, name)):
                self._reply(query, state_key(p, name), state_payload(node))
            if ke.intersects(snapshot_key(p, name)):
                self._reply(query, snapshot_key(p, name), self.snapshot(node))
            for sp in self.by_node.get(name, ()):
                if ke.intersects(sp.key):
                    self._reply(query, sp.key, self._value_now(node, sp.sig))

    async def dispatch(self, key: str, payload: bytes | None, type_param: str | None = None) -> Any:
        """Answer one concrete query key (also usable without zenoh, e.g. from tests)."""
        req = parse_key(self.prefix, key)
        if req.kind == "catalog":
            return self.catalog()
        rt = self.commands.node(req.node)
        node = rt.image
        if req.kind == "snapshot":
            return self.snapshot(node)
        if req.kind == "state":
            return state_payload(node)
        if req.kind == "nmt":
            cmd = nmt_command(payload)
            self.commands.nmt(req.node, cmd)
            return {"ok": True, "node": req.node, "nmt": cmd}
        if req.kind == "sdo":
            return await self._sdo(req, payload, type_param)
        if req.kind == "value":
            sig = self.commands.signal(rt, req.signal)
            if sig.transport == "sdo":
                raw = await self.commands.read_signal(req.node, req.signal)
                sc = self.scaling(req.node, sig)
                return {
                    "value": engineering(sig, raw, sc),
                    "unit": sc.unit,
                    "ts": time.time(),
                    "quality": "good",
                    "seq": None,
                    "source": "sdo",
                }
            return self._value_now(node, sig)
        if req.kind == "set":
            return await self._set(req, payload)
        if req.kind == "set_many":
            body = set_many_body(payload)
            raws = {}
            for name, value in body.items():
                sig = self.commands.signal(rt, name)
                raws[name] = to_raw(sig, value, self.scaling(req.node, sig))
            await self.commands.write_signals(req.node, raws)
            return {"ok": True, "node": req.node, "written": raws}
        raise ValueError(f"unsupported request {req.kind}")  # pragma: no cover

    async def _sdo(self, req: Request, payload: bytes | None, type_param: str | None) -> Any:
        assert req.obj is not None
        obj = str(req.obj)
        if payload:
            value, typ = sdo_write_body(payload)
            await self.commands.sdo_write(req.node, req.obj, value, typ or type_param)
            return {"ok": True, "node": req.node, "object": obj, "value": reply_value(value)}
        value = await self.commands.sdo_read(req.node, req.obj, type_param)
        return {"node": req.node, "object": obj, "value": reply_value(value)}

    async def _set(self, req: Request, payload: bytes | None) -> Any:
        rt = self.commands.node(req.node)
        sig = self.commands.signal(rt, req.signal)
        body = set_body(payload)
        via = "rpdo" if rt.is_output(req.signal) else "sdo"
        if body.bits is not None:
            named = {b.name: b for b in sig.bits}
            bits: dict[int, bool] = {}
            for bname, on in body.bits.items():
                b = named.get(bname)
                if b is None:
                    raise ValueError(f"{req.signal} has no bit {bname!r}; bits: {sorted(named)}")
                if not b.writable or b.width != 1:
                    writable = sorted(n for n, x in named.items() if x.writable and x.width == 1)
                    raise ValueError(
                        f"bit {bname} of {req.signal} is not writable; writable: {writable}"
                    )
                bits[b.bit] = on
            await self.commands.write_bits(req.node, req.signal, bits)
            return {
                "ok": True,
                "node": req.node,
                "signal": req.signal,
                "bits": body.bits,
                "via": via,
            }
        raw = body.value if body.raw else to_raw(sig, body.value, self.scaling(req.node, sig))
        await self.commands.write_signal(req.node, req.signal, raw)
        return {
            "ok": True,
            "node": req.node,
            "signal": req.signal,
            "value": body.value,
            "raw": raw,
            "via": via,
        }

    # ------------------------------------------------------------------ read-only answers
    def _value_now(self, node: NodeImage, sig: Signal) -> dict[str, Any]:
        sv = node.signals[sig.name]
        return value_payload(sig, sv, node.quality(sv), self.scaling(node.name, sig))

    def snapshot(self, node: NodeImage) -> dict[str, Any]:
        rt = self.commands.node(node.name)
        values = {
            sig.name: self._value_now(node, sig)
            for sig in rt.lp.profile.signals
            if sig.transport == "pdo"
        }
        return {"node": node.name, "state": state_payload(node), "values": values}

    def catalog(self) -> dict[str, Any]:
        """The app's catalogue (types, units, Modbus addresses) with this node's Zenoh keys and
        the scaling in force (overrides applied)."""
        cat = dict(self.catalog_fn()) if self.catalog_fn else {"nodes": {}}
        p = self.prefix
        cat["prefix"] = p
        for name, n in cat.get("nodes", {}).items():
            try:
                rt = self.commands.node(name)
            except GatewayError:
                continue
            n["keys"] = {
                "alive": alive_key(p, name),
                "state": state_key(p, name),
                "emcy": emcy_key(p, name),
                "snapshot": snapshot_key(p, name),
                "nmt": nmt_key(p, name),
                "set": set_key(p, name),
            }
            for sname, s in n.get("signals", {}).items():
                try:
                    sig = rt.lp.profile.signal(sname)
                except KeyError:
                    continue
                sc = self.scaling(name, sig)
                s["unit"], s["scale"], s["offset"] = sc.unit, sc.scale, sc.offset
                keys: dict[str, str] = {}
                if (name, sname) in self.pubs:
                    keys["value"] = value_key(p, name, sname)
                elif sig.transport == "sdo" and sig.access != "wo":
                    keys["get"] = value_key(p, name, sname)
                if is_writable(sig):
                    keys["set"] = set_key(p, name, sname)
                s["zenoh"] = keys
        return cat
