"""The Zenoh session's lifecycle, an object of its own (``ZenohSession``) that ``ZenohBridge``
(``bridge.py``) composes: the session configuration from ours, opening with the
duplicate-prefix check (``PrefixInUse``: an error for Zenoh only, the gateway starts without
its session, says why in ``problem`` and retries), the background re-open, the
declarations of publishers, tokens and queryable once a session is open, and the stop. It
holds the session, the event and raw-PDO publishers, the liveliness tokens and its tasks (the
re-open, the housekeeping); it knows its host by ``SessionHost``, a Protocol of what it reads
(what to publish, the pair's state) and of the hooks it calls (``attach``, ``detach``,
``on_pdo``, ``on_heard``, ``housekeeping``, ``node_alive``, ``events_ready``). None of it runs per frame.

Imports: zenoh, config, northbound.keys, zenoh_bridge.pair; commands, image, zenoh_bridge.plan
and zenoh_bridge.queries for types only (its host is the ``SessionHost`` Protocol, not the bridge).
Never modbus/ nor bus/.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

import zenoh
import zenoh.ext

from canopen_gateway.config import Config
from canopen_gateway.northbound.keys import GATEWAY_TOKEN, alive_key, emcy_key, pdo_key, state_key
from canopen_gateway.zenoh_bridge.pair import active_key, member_key, refusal

if TYPE_CHECKING:
    from canopen_gateway.commands import NodeInfo
    from canopen_gateway.image import NodeImage, ProcessImage
    from canopen_gateway.zenoh_bridge.plan import PdoPub, SignalPub
    from canopen_gateway.zenoh_bridge.queries import QueryService

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
#: time between the starts of two attempts to open a client session (the last one repeats)
REOPEN_SCHEDULE_S = (0.5, 1.0, 2.0, 5.0)
#: how long ``open`` waits for a connection to a configured router before asking it whether
#: our prefix is taken (peer mode connects in the background)
CONNECT_WAIT_S = 2.0
#: peer mode with ``zenoh.connect``: how often the session's routers and peers are looked at,
#: and how long after it opened "none of zenoh.connect answers" is said (``watch_connect``)
CONNECT_CHECK_S = 1.0
CONNECT_GRACE_S = 3.0
#: how long the liveliness get of the duplicate check may take
DUPLICATE_CHECK_TIMEOUT_S = 2.0
#: gets of the duplicate-prefix check that find no token before this gateway counts itself
#: alone, this far apart
DUPLICATE_CHECK_ATTEMPTS = 3
DUPLICATE_CHECK_PAUSE_S = 0.15


class _Nodes(Protocol):
    def node(self, name: str) -> NodeInfo: ...


class SessionHost(Protocol):
    """What the session needs of its host (``ZenohBridge``): what to declare (the planned
    publications, the nodes, the queries' service), the pair's state, and the hooks it calls
    when the session starts and stops, a PDO passes or the other member is heard."""

    @property
    def cfg(self) -> Config: ...
    @property
    def prefix(self) -> str: ...
    @property
    def image(self) -> ProcessImage: ...
    @property
    def commands(self) -> _Nodes: ...  # the nodes' PDO COB-IDs (raw PDOs)
    @property
    def pubs(self) -> Mapping[Any, SignalPub]: ...
    @property
    def pdo_pubs(self) -> Mapping[Any, PdoPub]: ...
    @property
    def queries(self) -> QueryService: ...
    @property
    def member(self) -> tuple[int, int] | None: ...
    @property
    def publishing(self) -> bool: ...
    @property
    def zid(self) -> str: ...
    @property
    def silent(self) -> frozenset[str]: ...

    def attach(self) -> None: ...
    async def detach(self) -> None: ...
    async def housekeeping(self) -> None: ...
    def node_alive(self, node: NodeImage) -> bool: ...
    def on_heard(self, key: str, payload: bytes, timestamp: Any) -> None: ...
    def on_pdo(self, node: NodeImage, cob_id: int, data: bytes) -> None: ...
    def events_ready(self) -> None: ...


class PrefixInUse(RuntimeError):
    """Another participant announces a gateway under our prefix: two gateways must not share
    one. The session stays closed while it does (``ZenohSession.problem``)."""


def zenoh_config(cfg: Config, zid: str | None = None) -> zenoh.Config:
    """The session configuration: our keys first (``zid``: the session's id, the one the
    gateway's own timestamps carry), then ``zenoh.json5`` (raw keys) on top."""
    z = cfg.zenoh
    conf = zenoh.Config()
    if zid is not None:
        conf.insert_json5("id", json.dumps(zid))
    conf.insert_json5("mode", json.dumps(z.mode))
    if z.mode == "peer":  # a client does not listen
        conf.insert_json5("listen/endpoints", json.dumps(z.listen))
    conf.insert_json5("connect/endpoints", json.dumps(z.connect))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(z.multicast_scouting))
    if z.mode == "client":
        conf.insert_json5("connect/timeout_ms", json.dumps(CLIENT_CONNECT_TIMEOUT_MS))
    if z.history.heartbeat_ms == 0 and (z.history.values > 0 or z.history.events > 0):
        # zenoh-ext: an advanced publisher without miss detection sequences its samples by
        # timestamp, and its declaration fails unless the session timestamps
        conf.insert_json5("timestamping/enabled", "true")
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


class ZenohSession:
    """The session of one bridge, from open to stop (event loop; ``other_gateway`` on a worker
    thread). ``clock`` and ``sleep`` are injectable (retries, waits)."""

    def __init__(self, bridge: SessionHost, clock: Callable[[], float] = time.monotonic) -> None:
        self.bridge = bridge
        self.cfg = bridge.cfg
        self.prefix = bridge.prefix
        self.session: zenoh.Session | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.up = False
        self.clock = clock
        self.sleep: Callable[[float], Any] = asyncio.sleep
        #: when the last attempt to open a session started (``clock``)
        self.last_attempt_s = 0.0
        self.state_pubs: dict[str, Any] = {}
        self.emcy_pubs: dict[str, Any] = {}
        self.raw_pubs: dict[tuple[str, int], Any] = {}
        self.tokens: dict[str, Any] = {}
        self.queryable: Any = None
        self.pair_tokens: dict[str, Any] = {}
        self.heard_sub: Any = None
        self._opened: zenoh.Session | None = None  # open, checked, not declared yet
        self._open_failed: zenoh.ZError | PrefixInUse | None = None
        #: why the session is not open when that needs a person (another participant
        #: announces our prefix), None otherwise; /healthz names it
        self.problem: str | None = None
        self._tasks: list[asyncio.Task[Any]] = []

    async def open(self) -> None:
        """Open the session and make sure no other gateway runs under our prefix; called by
        the app before the bus starts. Another participant announcing our prefix
        (``PrefixInUse``) is an error for Zenoh only: the session stays closed, ``problem``
        says why and ``start`` retries in the background. Raises zenoh.ZError in peer mode
        when the session cannot be opened at all."""
        self.loop = self.bridge.queries.loop = asyncio.get_running_loop()
        conf = zenoh_config(self.cfg, self.bridge.zid)  # a bad config raises here, before anything runs
        self.last_attempt_s = self.clock()
        try:
            self._opened = await self.open_checked(conf)
        except PrefixInUse as exc:
            self.problem = str(exc)
            self._open_failed = exc
        except zenoh.ZError as exc:
            if self.cfg.zenoh.mode != "client":
                raise
            self._open_failed = exc

    async def start(self) -> None:
        bridge = self.bridge
        if self.loop is None:
            await self.open()
        bridge.attach()
        opened, self._opened = self._opened, None
        if opened is not None:
            try:
                self.declare(opened)
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
        elif isinstance(self._open_failed, PrefixInUse):
            log.error("%s; Zenoh stays closed meanwhile and the gateway retries (Modbus and "
                      "the bus run)", self._open_failed)  # fmt: skip
            self._tasks.append(asyncio.create_task(self.reopen(), name="zenoh-open"))
        else:
            log.warning("%s", self.no_router(self._open_failed))
            log.debug("Zenoh: %s", self._open_failed)
            self._tasks.append(asyncio.create_task(self.reopen(), name="zenoh-open"))
        self._tasks.append(asyncio.create_task(bridge.housekeeping(), name="zenoh-housekeeping"))
        self._tasks.append(asyncio.create_task(self.watch_connect(), name="zenoh-connect"))

    async def open_checked(self, conf: zenoh.Config) -> zenoh.Session:
        """A new session, once no other gateway is announced under our prefix."""
        opening = asyncio.get_running_loop().run_in_executor(None, zenoh.open, conf)
        try:
            session = await asyncio.shield(opening)
        except asyncio.CancelledError:  # stopped while opening: close what the thread opens
            opening.add_done_callback(_close_opened)
            raise
        try:
            if self.cfg.zenoh.refuse_duplicate_prefix:
                other = await asyncio.to_thread(self.other_gateway, session)
                if other:
                    raise PrefixInUse(
                        f"another participant announces a gateway under Zenoh prefix "
                        f"{self.prefix} (token {other} is present): give this gateway its own "
                        "gateway.name or zenoh.prefix, or stop the other one (on a router "
                        "with the shipped access control only this gateway's user may)"
                    )
        except BaseException:
            await asyncio.to_thread(session.close)
            raise
        return session

    def other_gateway(self, session: zenoh.Session) -> str | None:
        """Worker thread: the key of a gateway token under our prefix, if one is announced and
        this gateway is not its partner in a hot-standby pair (``pair.refusal``)."""
        z = self.cfg.zenoh
        if z.connect:  # wait (bounded) for the configured router(s) to be connected
            deadline = self.clock() + CONNECT_WAIT_S
            while self.clock() < deadline:
                info = session.info
                if list(info.routers_zid()) or list(info.peers_zid()):
                    break
                time.sleep(0.02)
        # right after connecting to a router or peer, the routing may not reach every token
        # yet: the tokens of a few gets are taken together before this gateway counts itself
        # alone (or a pair's partner present)
        tokens: set[str] = set()
        for attempt in range(DUPLICATE_CHECK_ATTEMPTS if z.connect else 1):
            if attempt:
                time.sleep(DUPLICATE_CHECK_PAUSE_S)
            tokens |= {
                str(r.ok.key_expr)
                for r in session.liveliness().get(
                    alive_key(self.prefix, "**"), timeout=DUPLICATE_CHECK_TIMEOUT_S
                )
                if r.ok is not None
            }
        return refusal(tokens, self.prefix, self.bridge.member)

    async def reopen(self) -> None:
        """Open the session in the background (client mode without a router, or our prefix
        announced by another participant); attempts *start* on the schedule (an attempt
        itself takes up to the connect timeout)."""
        attempt = 0
        while self.session is None:
            period = REOPEN_SCHEDULE_S[min(attempt, len(REOPEN_SCHEDULE_S) - 1)]
            await self.sleep(max(0.0, self.last_attempt_s + period - self.clock()))
            attempt += 1
            self.last_attempt_s = self.clock()
            try:
                session = await self.try_open()
            except zenoh.ZError as exc:
                if attempt in (1, 10) or attempt % 60 == 0:
                    log.warning("%s", self.no_router(exc, attempt + 1))
                log.debug("Zenoh: %s", exc)
                continue
            except PrefixInUse as exc:
                self.problem = str(exc)
                if attempt in (1, 10) or attempt % 60 == 0:
                    log.error("%s; retrying", exc)
                continue
            try:
                self.declare(session)
            except zenoh.ZError as exc:
                log.warning("Zenoh declarations failed: %s", exc)
                await asyncio.to_thread(session.close)
                continue
            self.problem = None
            log.info("Zenoh session %s open (%s), prefix %s", session.zid(), self.cfg.zenoh.mode, self.prefix)

    async def watch_connect(self) -> None:
        """Peer mode with ``zenoh.connect``: the session opens whether an endpoint answers or
        not (Zenoh retries in the background), so a router that is not there, a refused login
        or TLS handshake would go unsaid. While no router and no peer is connected (after
        ``CONNECT_GRACE_S``) ``up`` is False (``/healthz`` ``zenoh: false``, as a client without
        its router), with one line each time that changes."""
        z = self.cfg.zenoh
        if z.mode != "peer" or not z.connect:
            return
        since, reached = self.clock(), None
        while True:
            await self.sleep(CONNECT_CHECK_S)
            session = self.session
            if session is None:
                since, reached = self.clock(), None
                continue
            try:
                connected = bool(list(session.info.routers_zid()) or list(session.info.peers_zid()))
            except zenoh.ZError:
                continue
            if connected == reached or not (connected or self.clock() - since >= CONNECT_GRACE_S):
                continue
            if connected and reached is False:
                log.info("Zenoh (peer mode): connected again (zenoh.connect: %s)", ", ".join(z.connect))
            elif not connected:
                log.warning(
                    "Zenoh (peer mode): none of zenoh.connect answers (%s): the session reaches no "
                    "router and no peer; a refused login (zenoh.auth) or TLS handshake (zenoh.tls) "
                    "looks the same; /healthz says zenoh: false until one does", ", ".join(z.connect),
                )  # fmt: skip
            reached = connected
            self.up = connected

    def no_router(self, exc: BaseException | None, attempts: int = 1) -> str:
        """One plain line for a client session that could not open: where it looked, how many
        times, when it tries again; Zenoh's own text (with its Rust source locations) is logged
        at DEBUG only. A refused login or TLS handshake is not told apart from an absent router
        by Zenoh's error (both time out), so the line says what to check."""
        where = ", ".join(self.cfg.zenoh.connect) or "(no zenoh.connect endpoint)"
        tried = "" if attempts == 1 else f" after {attempts} attempts"
        wait = REOPEN_SCHEDULE_S[min(attempts - 1, len(REOPEN_SCHEDULE_S) - 1)]
        every = REOPEN_SCHEDULE_S[-1]
        again = f"retrying every {every:g} s"
        if wait != every:
            again = f"retrying in {wait:g} s, then less often, up to every {every:g} s"
        return (
            f"no Zenoh router at {where}{tried}: {again} (Modbus and the bus run meanwhile; "
            "check the router, the address, zenoh.auth and zenoh.tls)"
        )

    async def try_open(self) -> zenoh.Session:
        return await self.open_checked(zenoh_config(self.cfg, self.bridge.zid))

    def publisher(self, s: zenoh.Session, key: str, cache: int, **qos: Any) -> Any:
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
            sample_miss_detection=zenoh.ext.MissDetectionConfig(
                heartbeat=hb_ms / 1000.0, sporadic_heartbeat=None
            )
            if hb_ms
            else None,
            publisher_detection=True,
            **qos,
        )

    def declare(self, s: zenoh.Session) -> None:
        bridge = self.bridge
        hist = self.cfg.zenoh.history
        for sp in bridge.pubs.values():
            sp.pub = self.publisher(
                s, sp.key, hist.values, congestion_control=zenoh.CongestionControl.DROP
            )
        for pp in bridge.pdo_pubs.values():
            pp.pub = self.publisher(
                s, pp.key, hist.values, congestion_control=zenoh.CongestionControl.DROP
            )
        for name in bridge.image.nodes:
            for pubs, key in ((self.state_pubs, state_key), (self.emcy_pubs, emcy_key)):
                pubs[name] = self.publisher(
                    s,
                    key(self.prefix, name),
                    hist.events,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.INTERACTIVE_HIGH,
                    reliability=zenoh.Reliability.RELIABLE,
                )
        if self.cfg.zenoh.raw_pdo:
            self.declare_raw_pdo(s)
        # the queryable first: a client that sees the gateway's token may ask at once
        self.queryable = s.declare_queryable(f"{self.prefix}/**", bridge.queries.on_query)
        self.tokens[GATEWAY_TOKEN] = s.liveliness().declare_token(
            alive_key(self.prefix, GATEWAY_TOKEN)
        )
        self.declare_pair(s)
        self.session = s
        self.up = True
        for node in bridge.image.nodes.values():
            self.sync_token(node.name, bridge.node_alive(node))
        bridge.events_ready()  # events made while no session was open go out now

    def declare_pair(self, s: zenoh.Session) -> None:
        """A hot-standby pair (``pair.py``): the member token always, the active token while
        this gateway publishes, else the subscriber that hears the other one's seq, with the
        history of its advanced publishers (event loop)."""
        bridge = self.bridge
        if bridge.member is None:
            return
        master_node_id, pair_node_id = bridge.member
        publishing = bridge.publishing
        wanted = {
            member_key(self.prefix, master_node_id, pair_node_id): True,
            active_key(self.prefix, pair_node_id): publishing,
        }
        for key, on in wanted.items():
            token = self.pair_tokens.get(key)
            if on and token is None:
                self.pair_tokens[key] = s.liveliness().declare_token(key)
            elif not on and token is not None:
                del self.pair_tokens[key]
                token.undeclare()
        hears = not publishing or bool(bridge.silent)  # a pair per network: part stands by
        if not hears and self.heard_sub is not None:
            sub, self.heard_sub = self.heard_sub, None
            sub.undeclare()
        elif hears and self.heard_sub is None:
            # with history: what the other one published before this gateway started (its
            # advanced publishers' caches, e.g. the last state events) counts as heard too
            self.heard_sub = zenoh.ext.declare_advanced_subscriber(
                s,
                f"{self.prefix}/**",
                lambda sample: bridge.on_heard(
                    str(sample.key_expr), sample.payload.to_bytes(), sample.timestamp
                ),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
            )

    def declare_raw_pdo(self, s: zenoh.Session) -> None:
        """Raw bytes of every TPDO received and every RPDO sent, on ``<node>/pdo/<cob-id>``
        (the process image's PDO listeners: called on the reader thread for TPDOs)."""
        bridge = self.bridge
        for name in bridge.image.nodes:
            rt = bridge.commands.node(name)
            for cob_id in rt.pdo_cob_ids:
                self.raw_pubs[(name, cob_id)] = s.declare_publisher(
                    pdo_key(self.prefix, name, cob_id),
                    encoding=OCTETS,
                    congestion_control=zenoh.CongestionControl.DROP,
                )
        bridge.image.pdo_listeners.append(bridge.on_pdo)

    def sync_token(self, node: str, alive: bool) -> None:
        """The node's liveliness token while ``alive`` (its values usable), none otherwise."""
        s = self.session
        if s is None:
            return
        tok = self.tokens.get(node)
        if alive and tok is None:
            self.tokens[node] = s.liveliness().declare_token(alive_key(self.prefix, node))
        elif not alive and tok is not None:
            del self.tokens[node]
            try:
                tok.undeclare()
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
        await self.bridge.detach()
        s, self.session = self.session, None
        opened, self._opened = self._opened, None
        self.tokens.clear()
        self.pair_tokens.clear()
        self.heard_sub = None
        for sess in (s, opened):
            if sess is not None:
                await asyncio.to_thread(sess.close)
