"""The Zenoh session's lifecycle, for ``ZenohBridge`` (``bridge.py``): the session
configuration from ours, opening with the duplicate-prefix check (``PrefixInUse``), the
background re-open in client mode, the declarations of publishers, tokens and queryable once a
session is open, and the stop. The bridge binds these functions as its methods (``open``,
``start``, ``stop``...); none of them runs per frame.

Imports: zenoh, config, northbound.keys, zenoh_bridge.pair, zenoh_bridge.bridge (types only).
Never modbus/ nor bus/.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from typing import TYPE_CHECKING, Any

import zenoh
import zenoh.ext

from gateway.config import Config
from gateway.northbound.keys import GATEWAY_TOKEN, alive_key, emcy_key, pdo_key, state_key
from gateway.zenoh_bridge.pair import active_key, member_key, refusal

if TYPE_CHECKING:
    from gateway.zenoh_bridge.bridge import ZenohBridge

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


async def open(bridge: ZenohBridge) -> None:
    """Open the session and make sure no other gateway runs under our prefix; called by the
    app before the bus starts. Raises ``PrefixInUse`` (the session is closed then) or, in
    peer mode, zenoh.ZError when the session cannot be opened at all."""
    bridge.loop = bridge.queries.loop = asyncio.get_running_loop()
    conf = zenoh_config(bridge.cfg)  # a bad config raises here, before anything runs
    bridge._last_attempt_s = bridge._clock()
    try:
        bridge._opened = await bridge._open_checked(conf)
    except zenoh.ZError as exc:
        if bridge.cfg.zenoh.mode != "client":
            raise
        bridge._open_failed = exc


async def start(bridge: ZenohBridge) -> None:
    if bridge.loop is None:
        await bridge.open()
    bridge.image.value_listeners.append(bridge._on_values)
    bridge.image.batch_listeners.append(bridge._sender.wake_values)
    bridge.image.health_listeners.append(bridge._on_health)
    bridge._sender.start()
    bridge._events.start()
    opened, bridge._opened = bridge._opened, None
    if opened is not None:
        try:
            bridge._declare(opened)
        except zenoh.ZError:
            await asyncio.to_thread(opened.close)
            await bridge.stop()
            raise
        log.info(
            "Zenoh session %s open (%s), prefix %s",
            opened.zid(),
            bridge.cfg.zenoh.mode,
            bridge.prefix,
        )
    else:
        log.warning(
            "no Zenoh router reachable (%s); retrying in the background", bridge._open_failed
        )
        bridge._tasks.append(asyncio.create_task(bridge._reopen(), name="zenoh-open"))
    bridge._tasks.append(asyncio.create_task(bridge._housekeeping(), name="zenoh-housekeeping"))


async def open_checked(bridge: ZenohBridge, conf: zenoh.Config) -> zenoh.Session:
    """A new session, once no other gateway is announced under our prefix."""
    opening = asyncio.get_running_loop().run_in_executor(None, zenoh.open, conf)
    try:
        session = await asyncio.shield(opening)
    except asyncio.CancelledError:  # stopped while opening: close what the thread opens
        opening.add_done_callback(_close_opened)
        raise
    try:
        if bridge.cfg.zenoh.refuse_duplicate_prefix:
            other = await asyncio.to_thread(bridge._other_gateway, session)
            if other:
                raise PrefixInUse(
                    f"another gateway already runs under Zenoh prefix {bridge.prefix} "
                    f"(token {other} is present): give this gateway its own gateway.name "
                    "or zenoh.prefix, or stop the other one"
                )
    except BaseException:
        await asyncio.to_thread(session.close)
        raise
    return session


def other_gateway(bridge: ZenohBridge, session: zenoh.Session) -> str | None:
    """Worker thread: the key of a gateway token under our prefix, if one is announced and
    this gateway is not its partner in a hot-standby pair (``pair.refusal``)."""
    z = bridge.cfg.zenoh
    if z.connect:  # wait (bounded) for the configured router(s) to be connected
        deadline = bridge._clock() + CONNECT_WAIT_S
        while bridge._clock() < deadline:
            info = session.info
            if list(info.routers_zid()) or list(info.peers_zid()):
                break
            time.sleep(0.02)
    tokens = [
        str(r.ok.key_expr)
        for r in session.liveliness().get(
            alive_key(bridge.prefix, "**"), timeout=DUPLICATE_CHECK_TIMEOUT_S
        )
        if r.ok is not None
    ]
    return refusal(tokens, bridge.prefix, bridge.member)


async def reopen(bridge: ZenohBridge) -> None:
    """Client mode: open the session in the background; attempts *start* on the schedule
    (an attempt itself takes up to the connect timeout)."""
    attempt = 0
    while bridge.session is None:
        period = REOPEN_SCHEDULE_S[min(attempt, len(REOPEN_SCHEDULE_S) - 1)]
        await bridge._sleep(max(0.0, bridge._last_attempt_s + period - bridge._clock()))
        attempt += 1
        bridge._last_attempt_s = bridge._clock()
        try:
            session = await bridge._try_open()
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
            bridge._declare(session)
        except zenoh.ZError as exc:
            log.warning("Zenoh declarations failed: %s", exc)
            await asyncio.to_thread(session.close)
            continue
        log.info("Zenoh session %s open (client), prefix %s", session.zid(), bridge.prefix)


async def try_open(bridge: ZenohBridge) -> zenoh.Session:
    return await bridge._open_checked(zenoh_config(bridge.cfg))


def publisher(bridge: ZenohBridge, s: zenoh.Session, key: str, cache: int, **qos: Any) -> Any:
    """An advanced publisher (cache, miss detection, publisher detection), or a plain one
    when the cache size is 0."""
    if cache <= 0:
        return s.declare_publisher(key, encoding=JSON, **qos)
    hb_ms = bridge.cfg.zenoh.history.heartbeat_ms
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


def declare(bridge: ZenohBridge, s: zenoh.Session) -> None:
    hist = bridge.cfg.zenoh.history
    for sp in bridge.pubs.values():
        sp.pub = bridge._publisher(
            s, sp.key, hist.values, congestion_control=zenoh.CongestionControl.DROP
        )
    for pp in bridge.pdo_pubs.values():
        pp.pub = bridge._publisher(
            s, pp.key, hist.values, congestion_control=zenoh.CongestionControl.DROP
        )
    for name in bridge.image.nodes:
        for pubs, key in ((bridge.state_pubs, state_key), (bridge.emcy_pubs, emcy_key)):
            pubs[name] = bridge._publisher(
                s,
                key(bridge.prefix, name),
                hist.events,
                congestion_control=zenoh.CongestionControl.BLOCK,
                priority=zenoh.Priority.INTERACTIVE_HIGH,
                reliability=zenoh.Reliability.RELIABLE,
            )
    if bridge.cfg.zenoh.raw_pdo:
        bridge._declare_raw_pdo(s)
    bridge.tokens[GATEWAY_TOKEN] = s.liveliness().declare_token(
        alive_key(bridge.prefix, GATEWAY_TOKEN)
    )
    bridge.queryable = s.declare_queryable(f"{bridge.prefix}/**", bridge.queries.on_query)
    bridge._declare_pair(s)
    bridge.session = s
    bridge.up = True
    for node in bridge.image.nodes.values():
        bridge._sync_token(node)


def declare_pair(bridge: ZenohBridge, s: zenoh.Session) -> None:
    """A hot-standby pair (``pair.py``): the member token always, the active token while this
    gateway publishes, else the subscriber that hears the other one's seq, with the history
    of its advanced publishers (event loop)."""
    if bridge.member is None:
        return
    master_node_id, pair_node_id = bridge.member
    wanted = {
        member_key(bridge.prefix, master_node_id, pair_node_id): True,
        active_key(bridge.prefix, pair_node_id): bridge.publishing,
    }
    for key, on in wanted.items():
        token = bridge.pair_tokens.get(key)
        if on and token is None:
            bridge.pair_tokens[key] = s.liveliness().declare_token(key)
        elif not on and token is not None:
            del bridge.pair_tokens[key]
            token.undeclare()
    heard = bridge.heard
    if bridge.publishing and bridge.heard_sub is not None:
        sub, bridge.heard_sub = bridge.heard_sub, None
        sub.undeclare()
    elif not bridge.publishing and bridge.heard_sub is None:
        # with history: what the other one published before this gateway started (its
        # advanced publishers' caches, e.g. the last state events) counts as heard too
        bridge.heard_sub = zenoh.ext.declare_advanced_subscriber(
            s,
            f"{bridge.prefix}/**",
            lambda sample: heard.on_sample(str(sample.key_expr), sample.payload.to_bytes()),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        )


def declare_raw_pdo(bridge: ZenohBridge, s: zenoh.Session) -> None:
    """Raw bytes of every TPDO received and every RPDO sent, on ``<node>/pdo/<cob-id>``
    (the process image's PDO listeners: called on the reader thread for TPDOs)."""
    for name in bridge.image.nodes:
        rt = bridge.commands.node(name)
        for cob_id in rt.pdo_cob_ids:
            bridge.raw_pubs[(name, cob_id)] = s.declare_publisher(
                pdo_key(bridge.prefix, name, cob_id),
                encoding=OCTETS,
                congestion_control=zenoh.CongestionControl.DROP,
            )
    bridge.image.pdo_listeners.append(bridge._on_pdo)


async def stop(bridge: ZenohBridge) -> None:
    bridge.up = False
    for t in bridge._tasks:
        t.cancel()
    for t in bridge._tasks:
        try:
            await t
        except (asyncio.CancelledError, Exception):  # noqa: BLE001
            pass
    bridge._tasks.clear()
    if bridge._on_values in bridge.image.value_listeners:
        bridge.image.value_listeners.remove(bridge._on_values)
    if bridge._on_health in bridge.image.health_listeners:
        bridge.image.health_listeners.remove(bridge._on_health)
    if bridge._sender.wake_values in bridge.image.batch_listeners:
        bridge.image.batch_listeners.remove(bridge._sender.wake_values)
    if bridge._on_pdo in bridge.image.pdo_listeners:
        bridge.image.pdo_listeners.remove(bridge._on_pdo)
    await asyncio.to_thread(bridge._sender.stop)  # marked values go out before the close
    await asyncio.to_thread(bridge._events.stop)  # and queued events
    s, bridge.session = bridge.session, None
    opened, bridge._opened = bridge._opened, None
    bridge.tokens.clear()
    bridge.pair_tokens.clear()
    bridge.heard_sub = None
    for sess in (s, opened):
        if sess is not None:
            await asyncio.to_thread(sess.close)
