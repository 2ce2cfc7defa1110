"""Builds the running gateway from a config: bus driver, master, process image, command service,
Modbus server, Zenoh bridge, health endpoint, and (for demos/tests) simulated devices.

``Gateway(cfg, nodes)`` then ``await start()`` / ``await stop()``: ``nodes`` are the config's
nodes resolved once when it was loaded (``gateway.checks.load_checked``), handed to the master,
Modbus, Zenoh, the web console and the simulator. The only module that knows every part; the
parts do not know each other except through the image and the command service.

Imports: every part: ascii.server, bus.can_backend, bus.driver, bus.master, checks, commands, config, device.resolved,
http.server, http.metrics, image, modbus.server, northbound (frames, regmap, summary), profiles.derived,
sim (faults, motion, node, runner), runtime (startup, threads, turns), journal, web (console, views), zenoh_bridge.bridge.
"""

from __future__ import annotations

import asyncio
import gc
import json
import logging
import time
from typing import Any

import can

from gateway import __version__
from gateway.bus.can_backend import open_can_bus
from gateway.bus.driver import BusDriver, BusOpenFailed
from gateway.bus.master import Master
from gateway.checks import check_config, journal_path
from gateway.commands import CommandService
from gateway.config import Config, ConfigError, blame
from gateway.device.resolved import ResolvedNode
from gateway.http.metrics import modbus_function_label
from gateway.http.server import pair_status
from gateway.image import ProcessImage
from gateway.journal import Entry, Journal, ntp64_of_time
from gateway.modbus.server import ModbusGateway
from gateway.northbound.frames import FrameDecoder
from gateway.northbound.keys import audit_key, prefix_of
from gateway.northbound.regmap import PAIR_ROLE_CODES, build_register_map
from gateway.northbound.summary import summarize
from gateway.profiles.derived import text_rows_as_signals
from gateway.runtime.startup import StartupError, listeners_of, ports_in_use, startup_step
from gateway.runtime.threads import ThreadRegistry
from gateway.runtime.turns import LoopTurns
from gateway.zenoh_bridge.bridge import ZenohBridge

log = logging.getLogger("gateway")


class SimulatedBus:
    """Simulated nodes of a config on their own connection to the configured bus."""

    def __init__(
        self,
        cfg: Config,
        nodes: dict[str, ResolvedNode],
        names: list[str] | None = None,
    ):
        from gateway.sim.motion import MotionConfig
        from gateway.sim.node import SimNode

        self.cfg = cfg
        wanted = names if names is not None else [n.name for n in cfg.simulated_nodes()]
        self.nodes: dict[str, Any] = {}
        for n in cfg.nodes:
            if n.name not in wanted:
                continue
            # a motion or an option the simulator refuses is a config error naming its key
            key = f"simulate.motion.{n.name}"
            try:
                MotionConfig.from_dict(cfg.simulate.motion.get(n.name))
                key = f"simulate.options.{n.name}"
                self.nodes[n.name] = SimNode(
                    nodes[n.name].lp,
                    n.node_id,
                    motion=cfg.simulate.motion.get(n.name),
                    options=cfg.simulate.options.get(n.name),
                )
            except (ValueError, TypeError) as exc:
                raise ConfigError([f"{blame(key, cfg.source, cfg.env_keys)}: {key}: {exc}"]) from exc
        self.bus: can.BusABC | None = None
        self.runner: Any = None

    def start(self) -> None:
        from gateway.sim.runner import SimRunner

        if not self.nodes:
            return
        self.bus = open_can_bus(self.cfg.can.bus_kwargs())  # socketcand: ours, see can_backend
        self.runner = SimRunner(self.bus, list(self.nodes.values()))
        self.runner.start()

    def stop(self) -> None:
        if self.runner is not None:
            self.runner.stop()
            self.runner = None
        if self.bus is not None:
            self.bus.shutdown()
            self.bus = None


class Gateway:
    def __init__(
        self,
        cfg: Config,
        nodes: dict[str, ResolvedNode],
        simulate: bool = True,
        *,
        passive: bool = False,
        bus_must_open: bool = False,
        freeze_gc: bool = False,
    ):
        #: every node resolved once (profile, settings, boot steps, codecs) for every part
        self.nodes = nodes
        #: a bus that cannot open stops the start (``BusOpenFailed``) instead of being retried
        self.bus_must_open = bus_must_open
        #: once started, what was built is moved out of the collector's reach (``gc.freeze``):
        #: a full collection of it took about 90 ms, a stall of every thread, the Modbus
        #: server's included; the bursts of garbage a query burst leaves start such collections
        self.freeze_gc = freeze_gc
        #: the console's and the ASCII clients' turns on the event loop: the PLC first
        self.turns = LoopTurns()
        check_config(cfg, self.nodes)  # the cross-checks of `canopen-gateway check` (ConfigError)
        self.cfg = cfg
        self.image = ProcessImage()
        self.threads = ThreadRegistry()
        self.driver = BusDriver(
            cfg.can.bus_kwargs(), self.image, cfg.can.reopen_backoff_s, threads=self.threads
        )
        self.master = Master(cfg, self.image, self.driver, passive=passive, nodes=self.nodes)
        self.commands = CommandService(self.master)
        self.modbus = (
            ModbusGateway(cfg, self.image, self.commands, self.nodes) if cfg.modbus.enabled else None
        )
        self.zenoh = (
            ZenohBridge(cfg, self.image, self.commands, self.catalog, threads=self.threads)
            if cfg.zenoh.enabled
            else None
        )
        self.sim = SimulatedBus(cfg, self.nodes) if simulate and cfg.simulated_nodes() else None
        jpath = journal_path(cfg)
        self.journal = (
            None
            if jpath is None
            else Journal(
                jpath,
                max_mb=cfg.journal.max_mb,
                values_ms=cfg.journal.values_ms,
                keep_days=cfg.journal.keep_days,
                sync=cfg.journal.sync,
            )
        )
        self.ascii: Any = None  # the CiA 309-3 ASCII gateway, when ``ascii:`` is configured
        self.health: Any = None
        self.web: Any = None
        self.started = False
        # a hot-standby pair: the adapters follow the role (the standby serves reads only)
        self.master.role_listeners.append(self._role_changed)
        self._role_changed(self.master.role or "", "start")

    def _role_changed(self, role: str, reason: str) -> None:
        """The pair's role changed (and once at construction): tell the adapters whether
        this gateway masters the bus."""
        mastering = self.master.mastering
        if self.modbus is not None:
            self.modbus.set_mastering(mastering)
        if self.zenoh is not None:
            self.zenoh.set_mastering(mastering)

    def catalog(self) -> dict[str, Any]:
        """Every node and signal: type, unit, scaling, Modbus address (for cloud discovery)."""
        rm = self.modbus.regmap if self.modbus else build_register_map(self.cfg, self.nodes)
        addr: dict[tuple[str, str], list[dict[str, Any]]] = {}
        for p in rm.points:
            if p.node and p.kind in ("signal", "bit"):
                addr.setdefault((p.node, p.name), []).append(
                    {"unit_id": p.unit, "table": p.table, "address": p.address, "count": p.count}
                    | ({"bit": p.bit} if p.bit is not None else {})
                )
        nodes = {}
        for name in self.commands.names():
            rt = self.commands.node(name)
            sigs = {}
            profile = rt.lp.profile
            for s in [*profile.signals, *text_rows_as_signals(profile)]:  # with the AP05 text rows
                sigs[s.name] = {
                    "object": str(s.object),
                    "type": s.type,
                    "access": s.access,
                    "transport": s.transport,
                    "unit": s.unit,
                    "scale": s.scale,
                    "offset": s.offset,
                    "description": s.description,
                    "bits": {b.name: b.bit for b in s.bits},
                    "modbus": addr.get((name, s.name), []),
                }
            nodes[name] = {
                "node_id": rt.node_id,
                "profile": rt.lp.family,
                "title": rt.lp.profile.title,
                "signals": sigs,
            }
        return {"gateway": self.cfg.gateway.name, "version": __version__, "nodes": nodes}

    def summary(self) -> str:
        parts = [f"canopen-gateway {__version__} '{self.cfg.gateway.name}'"]
        can_kw = self.cfg.can.bus_kwargs()
        parts.append(f"CAN {can_kw.get('interface')}:{can_kw.get('channel')}")
        if self.modbus:
            if self.cfg.modbus.plain:
                parts.append(f"Modbus TCP {self.cfg.modbus.host}:{self.modbus.port}")
            if self.modbus.tls_server is not None:
                parts.append(f"Modbus/TLS {self.modbus.tls_server.sockets[0].getsockname()[0]}:{self.modbus.tls_port}")
        if self.zenoh:
            z = self.cfg.zenoh
            endpoints = z.connect if z.mode == "client" else z.listen + z.connect  # a client listens nowhere
            parts.append(f"Zenoh {z.mode} {','.join(endpoints)} prefix {self.zenoh.prefix}")
        if self.ascii is not None:
            parts.append(f"CiA 309-3 ASCII {self.ascii.section.host}:{self.ascii.port}")
        if self.health is not None and self.health.port:
            url = f"http://{self.cfg.health.host}:{self.health.port}"
            parts.append(f"health {url}/healthz" + (f", web console {url}/" if self.web else ""))
        nodes = ", ".join(
            f"{n.name}={n.device}@{n.node_id}" + ("(sim)" if self.sim and n.name in self.sim.nodes else "")
            for n in self.cfg.nodes
        )
        parts.append(f"nodes: {nodes or 'none'}")
        return " | ".join(parts)

    def status(self) -> dict[str, Any]:
        """Readiness and per-node details for /healthz."""
        nodes = {}
        for name, node in self.image.nodes.items():
            s = summarize(node)
            age = s.data_age_s
            nodes[name] = {
                "node_id": s.node_id,
                "alive": s.alive,
                "operational": s.operational,
                "nmt_state": s.nmt_state.name.lower(),
                "lifecycle": s.lifecycle,
                "link": s.link.name.lower(),
                "data_age_s": None if age is None else round(age, 3),
                "last_error": s.last_error,
                "outputs": s.outputs,
            }
        bus_ok = self.driver.state == "ok"
        modbus_up = self.modbus is None or self.modbus.server is not None
        zenoh_up = self.zenoh is None or self.zenoh.up
        dead = self.threads.failures()
        # ready: the bus and the PLC side serve; the cloud side (Zenoh) counts only for a gateway
        # without Modbus (docs/deploy.md, Readiness): a probe must not take a PLC's gateway out
        # of service because the router is away. /healthz says "zenoh": false meanwhile.
        northbound_up = modbus_up if self.modbus is not None else zenoh_up
        out_of_pair = self.master.role == "duplicate"  # another device has our pair id
        ready = self.started and bus_ok and northbound_up and not dead and not out_of_pair
        return {
            "status": "ready" if ready else "not-ready",
            "ready": ready,
            "threads": {"failed": dead},
            "bus": {"state": self.driver.state, "detail": self.driver.last_error},
            "bus_peers": self.master.peers.doc(),
            "modbus": modbus_up,
            "zenoh": zenoh_up,
            "uptime_s": round(time.monotonic() - self.image.started_monotonic, 1),
            "nodes": nodes,
        } | self._pair_status() | self._watchdog_status() | self._journal_status()

    def _pair_status(self) -> dict[str, Any]:
        """``role`` and ``peer`` of a hot-standby pair (None outside one)."""
        pair = self.master.pair
        if pair is None:
            return pair_status(None, now_s=0.0, recent_s=0.0)
        redundancy = self.cfg.master.redundancy
        claim = pair.peer
        return pair_status(
            str(pair.role),
            now_s=self.master.clock(),
            recent_s=pair.timing.takeover_s,
            claim=None if claim is None else (claim.priority, claim.node_id, claim.at_s),
            peer_heartbeat_s=self.master.peer_heartbeat_s,
            peer_node_id=redundancy.peer_node_id if redundancy is not None else None,
            master_id=self.master.pair_master_id,
            conflict=self.master.pair_conflict,
            peer_role=pair.peer_role(self.master.clock()),
        )

    def _journal_status(self) -> dict[str, Any]:
        """The journal's figures and last error (a full or slow disk shows here; the gateway
        stays ready: it keeps serving without it)."""
        return {} if self.journal is None else {"journal": self.journal.status()}

    def audit(self, record: dict[str, Any]) -> None:
        """A write or command done or refused (the command service's audit hook): journaled
        under ``<prefix>/audit``."""
        if self.journal is None:
            return
        self.journal.append(
            Entry(ntp64_of_time(record["ts"]), "audit", audit_key(prefix_of(self.cfg)),
                  record.get("node"), None, json.dumps(record).encode())
        )

    def _watchdog_status(self) -> dict[str, Any]:
        if self.modbus is None or not self.modbus.watchdog.enabled:
            return {}
        wd = self.modbus.watchdog
        return {"modbus_watchdog": {"state": wd.state.value, "trips": dict(wd.trips)}}

    def overview(self) -> dict[str, Any]:
        """Gateway-wide figures for the web console's overview (counters become rates there)."""
        can_kw = self.cfg.can.bus_kwargs()
        doc: dict[str, Any] = {
            "can": {
                "interface": can_kw.get("interface"),
                "channel": str(can_kw.get("channel")),
                "bitrate": self.cfg.can.bitrate,
                "state": self.driver.state,
                "detail": self.driver.last_error,
                "reopens": self.driver.reopens,
            },
            "threads_failed": self.threads.failures(),
            "peers": self.master.peers.doc(),
            "pair": self._pair_status(),
            "counters": {},
        }
        if self.modbus is not None:
            store = self.modbus.store
            doc["modbus"] = {
                "listen": f"{self.cfg.modbus.host}:{self.modbus.port}",
                "serving": self.modbus.server is not None,
                "clients": len(self.modbus.connections),
                "requests": store.requests,
                "exceptions": sum(store.exceptions.values()),
                "read_only": self.cfg.modbus.read_only,
            }
            doc["counters"]["modbus_requests"] = store.requests
        if self.zenoh is not None:
            session = self.zenoh.session
            routers = peers = 0
            if session is not None:
                try:
                    routers = len(list(session.info.routers_zid()))
                    peers = len(list(session.info.peers_zid()))
                except Exception:  # a closing session: report none
                    pass
            doc["zenoh"] = {
                "mode": self.cfg.zenoh.mode,
                "up": self.zenoh.up,
                "prefix": self.zenoh.prefix,
                "endpoints": self.cfg.zenoh.listen + self.cfg.zenoh.connect,
                "routers": routers,
                "peers": peers,
                "publications": self.zenoh.publications,
            }
            doc["counters"]["zenoh_publications"] = self.zenoh.publications
        return doc

    async def start(self) -> None:
        """Start every part; on a failure, stop what started and raise ``StartupError`` (the
        setting and its value), so the process can exit with nothing left open."""
        try:
            await self._start()
        except StartupError as exc:  # the variable that set a key is blamed, not the file
            await self.stop()
            raise exc.blamed(self._env_var) from None
        except BaseException:
            await self.stop()
            raise

    def _env_var(self, key: str) -> str | None:
        where = blame(key, self.cfg.source, self.cfg.env_keys)
        return None if where == self.cfg.source else where

    async def _start(self) -> None:
        cfg = self.cfg
        # every port before anything opens: one failed start names every port in use
        busy = ports_in_use(listeners_of(cfg, modbus=self.modbus is not None, zenoh=self.zenoh is not None))
        if busy is not None:
            raise busy
        if self.journal is not None:
            # first: the events of this run are committed before they are published
            with startup_step("journal.path", cfg.journal.path):
                await asyncio.to_thread(self.journal.open)
            self.journal.start(self.threads)
            if self.zenoh is not None:
                self.zenoh.use_journal(self.journal)
            self.commands.audit = self.audit
        if self.zenoh is not None:
            z = cfg.zenoh
            key, where = ("zenoh.listen", z.listen) if z.mode == "peer" else ("zenoh.connect", z.connect)
            files = {
                f"zenoh.{section}.{k}": v
                for section in ("tls", "auth")
                for k, v in (getattr(z, section).model_dump() if getattr(z, section) else {}).items()
                if isinstance(v, str) and k.endswith(("_file", "certificate", "key"))
            }
            # before the bus: a second gateway under the same prefix stops here (PrefixInUse)
            with startup_step(key, ", ".join(where), files):
                await self.zenoh.open()
        if self.sim is not None:
            with startup_step("can.channel", cfg.can.channel):
                self._start_simulated_devices()
        with startup_step("can.interface", cfg.can.interface):
            await asyncio.to_thread(self.driver.open, must_open=self.bus_must_open)
        # every listener before the master sends its first frame: a start that fails on a port
        # in use must leave the devices as they were (no NMT command, no SDO, no heartbeat)
        if self.modbus is not None:
            with startup_step("modbus.port", f"{cfg.modbus.port} on {cfg.modbus.host}"):
                await self.modbus.start()
        if self.zenoh is not None:
            await self.zenoh.start()
        if self.cfg.ascii is not None and self.cfg.ascii.enabled:
            from gateway.ascii.server import AsciiGateway

            self.ascii = AsciiGateway(self.cfg, self.image, self.commands, self.turns)
            with startup_step("ascii.port", f"{self.cfg.ascii.port} on {self.cfg.ascii.host}"):
                await self.ascii.start()
        if cfg.health.port:
            with startup_step("health.port", f"{cfg.health.port} on {cfg.health.host}"):
                await self._start_health()
        await self.master.start()
        self.started = True
        if self.freeze_gc:
            gc.collect()
            gc.freeze()

    def _start_simulated_devices(self) -> None:
        """The simulated devices' own connection to the configured bus: with ``bus_must_open``
        a bus that cannot open stops the start as the gateway's own would (``BusOpenFailed``)."""
        assert self.sim is not None
        try:
            self.sim.start()
        except Exception as exc:
            if self.bus_must_open:
                raise BusOpenFailed(exc) from exc
            raise

    async def _start_health(self) -> None:
        from gateway.http.metrics import Metrics, NodeSample
        from gateway.http.server import HealthServer

        self.metrics = Metrics()

        def on_sdo(node: str, op: str, latency_s: float, abort: int | None) -> None:
            self.metrics.sdo_request(node, op)
            self.metrics.observe_sdo_latency(node, latency_s)
            if abort is not None:
                self.metrics.sdo_abort(node, abort)

        self.master.on_sdo = on_sdo
        self.metrics.set_node_source(
            lambda: [
                NodeSample(n.name, int(n.health.nmt_state), n.health.alive, n.data_age_s())
                for n in self.image.nodes.values()
            ]
        )
        self.web = None
        if self.cfg.web.enabled:
            from gateway.sim.faults import FaultInjector
            from gateway.web.console import WebConsole
            from gateway.web.views import ConsoleModel

            regmap = (
                self.modbus.regmap
                if self.modbus is not None
                else build_register_map(self.cfg, self.nodes)
            )
            self.web = WebConsole(
                ConsoleModel(self.cfg, self.image, self.commands, self.overview, regmap=regmap),
                decoder=FrameDecoder(self.cfg, self.nodes),
                faults=FaultInjector(self.sim) if self.sim is not None else None,
                frames=self.driver,
                turns=self.turns,
                journal=self.journal,
            )
            self.web.start(asyncio.get_running_loop())
        self.health = HealthServer(
            self.cfg.health.host,
            self.cfg.health.port,
            self.status,
            self.metrics.registry,
            app=self.web,
            turns=self.turns,
        )
        await self.health.start()
        self.metrics.set_refresh(self._copy_counters)

    def _copy_counters(self) -> None:
        """Copy the gateway's plain counters into the metrics (at every scrape)."""
        c = self.metrics.counters
        ic = self.image.counters
        c.frames_in, c.frames_out, c.bus_errors = ic["frames_in"], ic["frames_out"], ic["bus_errors"]
        peers = self.master.peers
        c.other_master = {kind: s.count for kind, s in peers.other_master.items()}
        c.other_sdo_client = {node: s.count for node, s in peers.sdo_clients.items()}
        c.bursts = ic["bursts"]
        pair = self.master.pair
        if pair is not None:
            c.pair_takeovers, c.pair_negotiations = pair.takeovers, pair.negotiations
            c.pair_duplicate_id_frames, c.pair_isolations = pair.duplicates, pair.isolations
        c.pair_role = PAIR_ROLE_CODES.get(self.master.role, 0)
        for name, node in self.image.nodes.items():
            for reason, n in (
                ("short", node.rx.pdo_too_short),
                ("too_long", node.rx.pdo_too_long),
                ("emcy_short", node.health.emcy_errors),
            ):
                if n:
                    c.decode_errors[(name, reason)] = n
            if node.health.emcy_count:
                c.emcy[name] = node.health.emcy_count
        if self.journal is not None:
            jc = self.journal.counts
            c.journal = {"written": jc.written, "dropped": jc.dropped, "removed": jc.removed}
        if self.zenoh is not None:
            c.zenoh_publications = self.zenoh.publications
            c.zenoh_refused = dict(self.zenoh.refused)
            q = self.zenoh.queries
            c.zenoh_queries_answered, c.zenoh_queries_busy = q.answered, q.busy
            c.zenoh_query_queue_depth = q.worker.depth
        c.northbound_turns_refused = self.turns.refused
        if self.modbus is not None:
            store = self.modbus.store
            c.modbus_exceptions = {f"0x{k:02X}": v for k, v in store.exceptions.items()}
            c.modbus_requests = {modbus_function_label(fc): n for fc, n in store.by_function.items()}
            c.modbus_watchdog_trips = dict(self.modbus.watchdog.trips)

    async def stop(self) -> None:
        self.started = False
        if self.ascii is not None:
            await self.ascii.stop()
        if self.health is not None:
            await self.health.stop()
            if self.web is not None:
                self.web.stop()
        if self.journal is not None:
            # what waits is committed and its events queued for the bridge, which stops next
            await asyncio.to_thread(self.journal.stop)
        if self.zenoh is not None:
            await self.zenoh.stop()
        if self.modbus is not None:
            await self.modbus.stop()
        await self.master.stop()
        await asyncio.to_thread(self.driver.close)
        if self.sim is not None:
            self.sim.stop()
