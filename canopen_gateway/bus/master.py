"""The CANopen master: a thin driver of one ``bus.node.node.Node`` per configured device.

It owns what the nodes must not: python-can (through ``BusDriver``), time and the event loop.

* **Reader thread -> event loop, in one place** (``_post``): the reader decodes process data
  itself (precompiled codecs, into the process image) and hands every control frame (boot-up,
  heartbeat, guarding answer, EMCY, SDO answer, guarding-bit echo) to the loop through one
  inbox, stamped with its bus-clock time; one ``loop.call_soon_threadsafe`` wakes the loop per
  burst, not per frame.
* **Event loop**: each event goes to its node, which returns what to do; ``_execute`` does it
  (frames to the sender thread, SDO results to the waiting command, values read by SDO into
  the image, health changes to the image's listeners, log lines). Then the node's timer is set
  to its ``next_deadline()``: the driver sleeps until a node needs time, it never polls.
* Each node's parts (``NodeParts``: config, profile, image, codecs, ``Node``) are built by
  ``bus/node/parts.py`` (``build_node``).
* **Services** for the command service: SDO upload/download (awaitable, one transfer per node
  at a time, queued in the node), RPDO outputs, NMT commands.
* **A hot-standby pair** (``master.redundancy``): the pair member (``bus/pair/member.py``)
  decides whether this gateway masters the bus; while it does not (``mastering`` False) the
  nodes only listen (``Node.stand_by``) and every frame a node would send is dropped here.

Imports: bus.* (bus.pair.member: a pair), device.resolved, pdo.codec, canopen.cia301, image, errors, config, canopen.objref, runtime.ratelimit, python-can.
Nothing northbound.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import can

from canopen_gateway.bus.bus_peers import (
    BusPeers,
)
from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.events import HealthChanged, Note, SdoDone, Send, ValuesRead
from canopen_gateway.bus.lss.service import LssService
from canopen_gateway.bus.node import listening
from canopen_gateway.bus.node.parts import NodeParts, build_node_into
from canopen_gateway.bus.pair.heard_sdo import HeardSdo
from canopen_gateway.bus.pair.member import PairMember, talk_period_s
from canopen_gateway.bus.pair.side import MASTER_HEARTBEAT, NoPair, PairSide
from canopen_gateway.bus.producers import Periodic
from canopen_gateway.bus.reader import (
    control_handler,
    peer_frame_handler,
    tpdo_handler,
    unknown_handler,
)
from canopen_gateway.bus.sdo.waiters import SdoWaiters
from canopen_gateway.canopen.cia301 import (
    COB_EMCY,
    COB_LSS_SLAVE,
    COB_NMT,
    COB_NMT_EC,
    COB_SDO_RX,
    COB_SDO_TX,
    COB_SYNC,
    NMT_COMMANDS,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.errors import BusDown, NodeNotOperational, NotActive, SdoAbort
from canopen_gateway.image import ProcessImage
from canopen_gateway.pdo.codec import TpdoCodec
from canopen_gateway.runtime.ratelimit import RateLimitedLog

log = logging.getLogger("gateway.master")

#: another master / another SDO client is logged at most once per kind and this period
PEER_LOG_PERIOD_S = 60.0

#: queued events that wake the loop even when none asked for it (a bound, never reached while
#: every quiet event's node has a deadline timer)
QUIET_LIMIT = 1024


class Master(PairSide):
    """The driver of the configured nodes (see the module docstring).

    ``passive = True`` (commissioning tools: ``canopen-gateway sdo|nmt``): supervision and the
    services only; no probe, no configuration, no NMT start of its own, SDO to any node.
    """

    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        driver: BusDriver,
        *,
        passive: bool = False,
        nodes: dict[str, ResolvedNode],
    ):
        self.cfg = cfg
        self.image = image
        self.driver = driver
        self.passive = passive
        self.clock: Callable[[], float] = driver.bus_clock
        self.loop: asyncio.AbstractEventLoop | None = None
        self.nodes: dict[str, NodeParts] = {}
        self.by_id: dict[int, NodeParts] = {}
        self.warn = RateLimitedLog(log)
        self._inbox: deque[tuple[Callable[..., None], tuple[Any, ...]]] = deque()
        self._drain_pending = False
        self._timers: dict[str, asyncio.TimerHandle] = {}
        self._producers: dict[str, asyncio.TimerHandle] = {}
        self._due: dict[str, float] = {}
        self._waiting = SdoWaiters()  # the SDO transfers clients await
        #: on_sdo(node, op "read"|"write", latency_s, abort_code or None), e.g. for metrics
        self.on_sdo: Callable[[str, str, float, int | None], None] | None = None
        #: this gateway in a hot-standby pair; outside one the null member (``NoPair``): the
        #: master consults it the same way, and it always masters
        self.member: PairMember | NoPair = NoPair()
        self._last_frame: tuple[float, float | None] = (0.0, None)  # (its timestamp, bus clock)
        known = {n.node_id for n in cfg.nodes}
        if cfg.master.redundancy is not None and not passive:
            self.member = PairMember(
                cfg, self._send_quiet, self.clock, self._role_changed, self._drain,
                last_frame_s=self._last_frame_s,
                nodes_alive=lambda: any(p.node.alive for p in self.nodes.values()),
                reader_busy=lambda: not driver.idle,
                talk_s=talk_period_s(nodes[n.name].settings for n in cfg.nodes),
            )  # fmt: skip
            known |= self.member.known_ids()
        #: True while this gateway masters the bus (always, outside a pair)
        self.mastering = not self.in_pair
        #: role listeners: called (role, reason) on the event loop when the pair's role changes
        self.role_listeners = self.member.role_listeners
        self.standby_dropped = 0  # frames the nodes asked for while this gateway stood by
        self.heard_sdo = HeardSdo()  # the other gateway's SDO transfers, heard standing by
        #: other masters, other SDO clients, unconfigured node ids (event loop only)
        self.peers = BusPeers(
            cfg.master.node_id,
            known,
            echo=bool(cfg.can.bus_kwargs().get("receive_own_messages")),
        )
        self.peer_log = RateLimitedLog(log, period_s=PEER_LOG_PERIOD_S)
        #: LSS (CiA 305) on this connection to the bus, for the command service
        self.lss = LssService(driver.send, self._post, self.clock, driver.frame_time)
        listening = passive or self.in_pair  # a pair's member, until it is active
        for ncfg in cfg.nodes:
            parts = build_node_into(nodes[ncfg.name], image, listening)
            self.nodes[ncfg.name] = parts
            self.by_id[ncfg.node_id] = parts
        self._install_handlers()

    # ------------------------------------------------------------------ reader thread
    def _install_handlers(self) -> None:
        taken: dict[int, str] = {}

        def install(cob_id: int, what: str, handler: Callable[[can.Message], None]) -> None:
            # one receiver per COB-ID: canopen_gateway.checks (every start) refuses two uses of one
            assert cob_id not in taken, (
                f"COB-ID 0x{cob_id:03X}: {what} would replace {taken[cob_id]} in the dispatch "
                "table; two uses of one COB-ID must be refused by the config check "
                "(canopen_gateway.checks.cob_id_problems)"
            )
            taken[cob_id] = what
            h[cob_id] = handler

        h = self.driver.handlers
        for p in self.nodes.values():
            for codec in p.tpdos:
                install(codec.cob_id, f"{p.name} TPDO{codec.number}", self._tpdo_handler(p, codec))
            install(COB_NMT_EC + p.node_id, f"{p.name} heartbeat", self._control(p, "nmt_ec"))
            install(COB_EMCY + p.node_id, f"{p.name} EMCY", self._control(p, "emcy"))
            install(COB_SDO_TX + p.node_id, f"{p.name} SDO response", self._control(p, "sdo"))
            if not self.peers.echo:  # our own requests come back with the echo on
                install(COB_SDO_RX + p.node_id, f"{p.name} SDO request",
                        self._peer_frame(self._on_sdo_request, p))  # fmt: skip
        install(COB_NMT, "NMT", self._peer_frame(self._on_nmt_frame))
        if self.in_pair:
            self._install_pair_handlers(install, taken)
        elif self.cfg.master.heartbeat_ms:  # without one the master's node id is not on the bus
            install(COB_NMT_EC + self.cfg.master.node_id, "the master's heartbeat",
                    self._peer_frame(self._on_own_heartbeat))  # fmt: skip
        install(COB_LSS_SLAVE, "LSS response", self.lss.reader_handler())
        self.driver.default_handler = unknown_handler(
            self.driver.rx_counters, self.warn, self._post, self.peers.on_talking
        )
        if self.image.end_batch not in self.driver.burst_listeners:
            self.driver.burst_listeners.append(self.image.end_batch)
        self.driver.on_state = self._bus_state

    def _post(self, fn: Callable[..., None], *args: Any, wake: bool = True) -> None:
        """The one hand-off from the reader thread to the event loop.

        Events go into an inbox; the loop is woken (``call_soon_threadsafe``) only when no
        drain is pending, so a burst of control frames costs one wake-up, not one per frame.
        The flag is cleared before the drain empties the inbox: an event put in after that
        schedules a new drain, none is left behind. ``wake=False`` queues an event that
        changes nothing before a deadline (a steady node's repeated heartbeat): it is drained
        at the next wake-up, at the latest by the node's deadline timer (``_tick``)."""
        inbox = self._inbox
        inbox.append((fn, args))
        if (wake or len(inbox) >= QUIET_LIMIT) and not self._drain_pending:
            loop = self.loop
            if loop is not None and not loop.is_closed():
                self._drain_pending = True
                loop.call_soon_threadsafe(self._drain)

    def _drain(self) -> None:
        self._drain_pending = False
        self.member.check()  # a stalled active gateway stands by before it acts
        inbox = self._inbox
        while inbox:
            fn, args = inbox.popleft()
            try:
                fn(*args)
            except Exception:  # noqa: BLE001 - one bad event must not stop the others
                log.exception("event %s failed", getattr(fn, "__name__", fn))

    def _control(self, p: NodeParts, kind: str) -> Callable[[can.Message], None]:
        return control_handler(p, kind, self._post, self._on_control, self.driver.frame_time)

    def _tpdo_handler(self, p: NodeParts, codec: TpdoCodec) -> Callable[[can.Message], None]:
        return tpdo_handler(
            p, codec, self.image, self.driver.rx_counters, self.warn, self._post, self._on_echo,
            self.driver.frame_time,
        )  # fmt: skip

    def _peer_frame(self, fn: Callable[..., None], *args: Any) -> Callable[[can.Message], None]:
        return peer_frame_handler(self._post, self.driver.frame_time, fn, *args)

    def _on_nmt_frame(self, data: bytes, wall: float, now: float) -> None:
        if not self.mastering and len(data) >= 2:
            # the active gateway of the pair commands the nodes: guarding expects what it says
            command = next((c for c, b in NMT_COMMANDS.items() if b == data[0]), None)
            for p in self.nodes.values():
                if command is not None and data[1] in (0, p.node_id):
                    p.node.on_nmt_command(command)
            return
        text = self.peers.on_nmt(data, wall, now)
        if text is not None:
            self.peer_log.warning(("other_master", "nmt"), "%s", text)

    def _on_own_heartbeat(self, data: bytes, wall: float, now: float) -> None:
        text = self.peers.on_own_heartbeat(data, wall, now)
        if text is not None:
            self.peer_log.warning(("other_master", "heartbeat"), "%s", text)

    def _on_sdo_request(self, p: NodeParts, data: bytes, wall: float, now: float) -> None:
        if not self.mastering:
            self.heard_sdo.on_request(p.node_id, data)  # the active gateway's transfer
            self._execute(p, listening.on_sdo_heard(p.node, now))  # a node being configured?
            return
        text = self.peers.on_sdo_request(p.name, p.node_id, data, wall)
        self.peer_log.info(("sdo_client", p.name), "%s", text, extra={"node": p.name})

    def _last_frame_s(self) -> float | None:
        """When the reader took its last frame, on the monotonic clock (None: none yet): its
        timestamp turned as the reader turns every frame's (``BusDriver.stamp``: a wall clock
        that stepped is not believed), once per timestamp, so that the same frame always gives
        the same time."""
        wall = self.driver.last_frame_wall
        if wall != self._last_frame[0]:
            self._last_frame = (wall, self.driver.stamp(wall) if wall else None)
        return self._last_frame[1]

    def _bus_state(self, state: str, detail: str) -> None:
        if state == "down":
            self._post(self._on_bus_down)
        if self.in_pair:  # down, or its frames cannot go out (error): the pair's role
            self._post(self.member.on_link, state)

    # ------------------------------------------------------------------ event loop
    def _on_control(self, p: NodeParts, kind: str, data: bytes, wall: float, now: float) -> None:
        node = p.node
        if kind == "nmt_ec":
            if not data:
                return
            outs = node.on_nmt_ec(data[0], now)
        elif kind == "rtr":  # another master's guarding RTR (heard while listening)
            outs = node.on_guard_rtr(now)
        elif kind == "emcy":
            outs = node.on_emcy(data, wall, now)
        else:
            if not self.mastering:
                self.heard_sdo.on_response(p.node_id, data)
            outs = node.on_sdo_response(data, now)
        self._execute(p, outs)

    def _on_echo(self, p: NodeParts, bit: int, now: float) -> None:
        self._execute(p, p.node.on_echo(bit, now))

    def _on_bus_down(self) -> None:
        now = self.clock()
        for p in self.nodes.values():
            self._execute(p, p.node.on_bus_down(now))

    def _tick(self, p: NodeParts) -> None:
        self._timers.pop(p.name, None)
        self._due.pop(p.name, None)
        self.member.check()  # a stalled active gateway stands by before it acts
        if self._inbox:
            self._drain()  # heartbeats queued without a wake-up count before any timeout
        self._execute(p, p.node.tick(self.clock()))

    def _execute(self, p: NodeParts, outs: list[Any]) -> None:
        health = False
        for o in outs:
            if isinstance(o, Send):
                sent = self._send_as_master(o.cob_id, o.data, rtr=o.rtr, dlc=o.dlc,
                                            record=o.cob_id == COB_NMT)  # fmt: skip
                if sent is None:
                    self.standby_dropped += 1  # a pair's standby sends nothing of the nodes'
                if not sent:
                    continue
                if o.rpdo:
                    for listener in self.image.pdo_listeners:
                        listener(p.image, o.cob_id, o.data)
            elif isinstance(o, HealthChanged):
                health = True
                if o.what != "state":
                    self.image.health_changed(p.image, o.what)
            elif isinstance(o, SdoDone):
                self._waiting.done(p.name, o)
            elif isinstance(o, ValuesRead):
                if p.image.is_bound(o.names):  # bound by build_node: the refresh plan
                    self.image.update(p.image, o.names, o.values, time.time(), p.loop_rx, o.valid_at_s)
                    self.image.end_batch()
                else:
                    self.warn.log(logging.ERROR, ("unbound", p.name),
                                  "node %s: values %s read but not a source in the image; dropped",
                                  p.name, o.names)  # fmt: skip
            elif isinstance(o, Note):
                text = o.text
                if "did not appear" in text:  # a wrong node id? say which ids talk instead
                    heard = [q.name for q in self.nodes.values() if q.image.health.alive]
                    text += self.peers.talking_hint(heard)
                text += self.driver.where  # several networks: " (network line2)", as bus lines
                if o.kind is not None:
                    self.warn.log(o.level, o.kind, "%s", text)
                else:
                    log.log(o.level, "%s", text)
        if health:
            self.image.health_changed(p.image, "state")
        p.steady = p.node.steady  # a deadline timer drains what is queued
        self._schedule(p)

    def _schedule(self, p: NodeParts) -> None:
        loop = self.loop
        if loop is None:
            return
        deadline = p.node.next_deadline()
        name = p.name
        if deadline is None:
            t = self._timers.pop(name, None)
            if t is not None:
                t.cancel()
            self._due.pop(name, None)
            return
        # node deadlines are on the bus clock, which may lag the loop's monotonic clock
        lag = max(0.0, loop.time() - self.clock())
        at = max(deadline + lag, loop.time() + (0.001 if deadline <= self.clock() else 0.0))
        if self._due.get(name) == at:
            return
        t = self._timers.pop(name, None)
        if t is not None:
            t.cancel()
        self._timers[name] = loop.call_at(at, self._tick, p)
        self._due[name] = at

    # ------------------------------------------------------------------ start / stop
    async def start(self) -> None:
        """Start the master: its heartbeat and SYNC producers, and every node's boot-up."""
        self.loop = asyncio.get_running_loop()
        t0 = self.loop.time()
        if self.cfg.master.heartbeat_ms:
            hb = Periodic(self.cfg.master.heartbeat_ms / 1000.0, t0)
            self._produce("heartbeat", hb, COB_NMT_EC + self.cfg.master.node_id, MASTER_HEARTBEAT)
        if self.cfg.master.sync_period_ms:
            self._produce(
                "sync", Periodic(self.cfg.master.sync_period_ms / 1000.0, t0), COB_SYNC, b""
            )
        self.member.start(self.loop)  # a pair's: its own heartbeat, its role
        self._producers["housekeeping"] = self.loop.call_later(
            self.warn.period_s, self._housekeeping
        )
        now = self.clock()
        for p in self.nodes.values():
            self._execute(p, p.node.start(now, probe=self.cfg.master.probe_at_start))

    async def stop(self) -> None:
        self.member.hand_over()  # an active member of a pair hands the bus to the standby first
        self.lss.stop()
        self.member.stop()
        for t in [*self._timers.values(), *self._producers.values()]:
            t.cancel()
        self._producers.clear()
        self._timers.clear()
        self._due.clear()
        self._waiting.fail_all(BusDown("gateway stopping"))

    def _produce(self, name: str, periodic: Periodic, cob_id: int, data: bytes) -> None:
        """SYNC / master heartbeat: send when due, then sleep until the next one."""
        loop = self.loop
        if loop is None:
            return
        self.member.check()
        if periodic.due(loop.time()):
            self._send_as_master(cob_id, data, record=True)
        self._producers[name] = loop.call_at(
            periodic.next_deadline(), self._produce, name, periodic, cob_id, data
        )

    def _send_as_master(
        self, cob_id: int, data: bytes, *, rtr: bool = False, dlc: int | None = None,
        record: bool = False,
    ) -> bool | None:
        """The one gate of what this gateway sends as the bus's NMT master (the nodes' frames,
        the logical heartbeat, SYNC): None, nothing sent, while a pair's member does not master
        the bus; False when the bus refused it; True when queued (``record``: kept for telling
        our own frames from another master's)."""
        if not self.mastering:
            return None
        try:
            self.driver.send(cob_id, data, rtr=rtr, dlc=dlc)
        except can.CanError:
            return False
        if record:
            self.peers.sent(cob_id, data, self.clock())
        return True

    def _housekeeping(self) -> None:
        """Summary lines of the rate-limited logs, once per period."""
        self.warn.flush()
        self.peer_log.flush()
        self.driver.warn.flush()
        assert self.loop is not None
        self._producers["housekeeping"] = self.loop.call_later(
            self.warn.period_s, self._housekeeping
        )

    # ------------------------------------------------------------------ services
    def part(self, name: str) -> NodeParts:
        return self.nodes[name]

    def require_active(self) -> None:
        """The role gate of every command: a member of a pair that does not master the bus
        refuses (``NotActive``); outside a pair it always masters."""
        self.member.check()
        if not self.mastering:
            role = self.role or "standby"
            raise NotActive(
                f"this gateway is the {role} one of a pair: send commands to the active one"
            )

    def require_bus(self) -> None:
        if self.loop is None:  # the listeners start before the master sends its first frame
            raise BusDown("the gateway is starting")
        self.require_active()
        if self.driver.state == "down":
            raise BusDown(self.driver.last_error or "CAN bus is down")

    def nmt(self, node: str, command: str) -> None:
        """NMT command to one node by name, or to every node with ``all`` (node id 0)."""
        self.require_bus()
        targets = list(self.nodes.values()) if node == "all" else [self.nodes[node]]
        node_id = 0 if node == "all" else targets[0].node_id
        frame = bytes([NMT_COMMANDS[command], node_id])
        try:
            self.driver.send(COB_NMT, frame)
        except can.CanError as exc:
            raise BusDown(str(exc)) from exc
        self.peers.sent(COB_NMT, frame, self.clock())
        for p in targets:
            p.node.on_nmt_command(command)

    def write_outputs(
        self, name: str, per_pdo: dict[int | None, dict[str, Any]], *, safe: bool = False
    ) -> None:
        """Set outputs of a node and send its RPDOs now (see ``Node.write_outputs``)."""
        self.require_bus()
        p = self.nodes[name]
        self._execute(p, p.node.write_outputs(per_pdo, self.clock(), wall=time.time(), safe=safe))
        self.image.outputs_written(p.image, tuple({n: 0 for v in per_pdo.values() for n in v}))

    async def sdo(
        self, name: str, obj: ObjRef, data: bytes | None, *, check_state: bool = True
    ) -> bytes:
        """One SDO upload (``data`` None; returns the bytes) or download; typed errors."""
        self.require_bus()
        p = self.nodes[name]
        if check_state and not self.passive and not p.image.health.alive:
            raise NodeNotOperational(name, "not alive")
        assert self.loop is not None
        t0 = self.loop.time()
        token, outs = p.node.request_sdo(obj, data, self.clock())
        fut = self._waiting.add(self.loop, name, token, obj)
        self._execute(p, outs)
        op = "read" if data is None else "write"
        try:
            result = await fut
        except SdoAbort as exc:
            if self.on_sdo is not None:
                self.on_sdo(name, op, self.loop.time() - t0, exc.code)
            raise
        if self.on_sdo is not None:
            self.on_sdo(name, op, self.loop.time() - t0, None)
        return result
