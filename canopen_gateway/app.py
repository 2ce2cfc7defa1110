"""Builds the running gateway from a config: one ``bus.network.Network`` per CAN network (its
bus driver and master), the process image, the command service (which routes by node name to
each node's network), Modbus server, Zenoh bridge, health endpoint, the command socket, and (for demos/tests)
simulated devices (``sim.buses.SimulatedBus``), each network's on its own bus.

``Gateway(cfg, nodes)`` then ``await start()`` / ``await stop()``: ``nodes`` are the config's
nodes resolved once when it was loaded (``canopen_gateway.checks.load_checked``), handed to the master,
Modbus, Zenoh, the web console and the simulator. The only module that knows every part; the
parts do not know each other except through the image and the command service.

Imports: every part: ascii.server, bus.driver, bus.master, bus.network, checks, command_socket,
commands, config, device.resolved, http (health, server, metrics, tls), image, modbus.server,
northbound (audit_values, catalog, frames, gateway_block, keys, regmap, summary), sim (buses,
faults), runtime (startup, threads, turns), journal (store, auditlog), web (console, monitor,
views), zenoh_bridge.bridge.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import ssl
import time
from typing import Any

from canopen_gateway import __version__
from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.master import Master
from canopen_gateway.bus.network import Network, NetworkOpenFailed, Networks
from canopen_gateway.checks import check_config, journal_path
from canopen_gateway.command_socket import CommandSocket
from canopen_gateway.commands import CommandService
from canopen_gateway.config import Config, ConfigError, blame
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.http.health import bus_reasons, network_overview, network_status, pair_of
from canopen_gateway.http.metrics import modbus_function_label
from canopen_gateway.image import ProcessImage
from canopen_gateway.journal import FileLock, Journal, JournalInUse
from canopen_gateway.journal.auditlog import AuditLog
from canopen_gateway.modbus.server import ModbusGateway
from canopen_gateway.northbound.audit_values import engineering_record
from canopen_gateway.northbound.catalog import build_catalog
from canopen_gateway.northbound.frames import FrameDecoder
from canopen_gateway.northbound.gateway_block import BUS_STATE_CODES, PAIR_ROLE_CODES
from canopen_gateway.northbound.keys import audit_key, prefix_of
from canopen_gateway.northbound.regmap import build_register_map
from canopen_gateway.northbound.summary import health_doc
from canopen_gateway.runtime.startup import StartupError, listeners_of, ports_in_use, startup_step
from canopen_gateway.runtime.threads import ThreadRegistry
from canopen_gateway.runtime.turns import LoopTurns
from canopen_gateway.sim.buses import SimulatedBus
from canopen_gateway.zenoh_bridge.bridge import ZenohBridge

log = logging.getLogger("gateway")


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
        views = cfg.network_views()
        #: one per CAN network (its driver, master, bus state), in configured order
        self.networks = Networks([
            Network(k, view, self.image, self.nodes, threads=self.threads, passive=passive,
                    named=cfg.networks is not None)
            for k, view in enumerate(views)
        ])  # fmt: skip
        #: the first network's driver and master (the only ones of a single-network gateway)
        self.driver: BusDriver = self.networks.first.driver
        self.master: Master = self.networks.first.master
        self.commands = CommandService(self.networks)
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
        #: the command line's way in when the bus is in-process (``command_socket``)
        self.command_socket = CommandSocket(cfg, self.commands, self.turns)
        self.health: Any = None
        self.web: Any = None
        self.started = False
        # a hot-standby pair: the adapters follow the role (the standby serves reads only)
        for net in self.networks:
            net.master.role_listeners.append(self._role_changed)
        self._role_changed(self.master.role or "", "start")

    def _role_changed(self, role: str, reason: str) -> None:
        """The pair's role changed (and once at construction): tell the adapters whether this
        gateway masters the bus (a pair per network: Zenoh publishes the networks it masters)."""
        mastering = any(net.master.mastering for net in self.networks)
        if self.modbus is not None:
            self.modbus.set_mastering(mastering)
        if self.zenoh is not None:
            silent = [n for net in self.networks if not net.master.mastering for n in net.master.nodes]
            self.zenoh.set_mastering(mastering, frozenset(silent))

    def catalog(self) -> dict[str, Any]:
        """Every network, node and signal: type, unit, scaling, Modbus address (for cloud
        discovery; ``northbound.catalog``)."""
        rm = self.modbus.regmap if self.modbus else build_register_map(self.cfg, self.nodes)
        return build_catalog(self.cfg, self.commands, rm)

    def summary(self) -> str:
        parts = [f"canopen-gateway {__version__} '{self.cfg.gateway.name}'"]
        for net in self.networks:
            can_kw = net.cfg.can.bus_kwargs()
            named = f" network {net.name}" if self.cfg.networks is not None else ""
            parts.append(f"CAN{named} {can_kw.get('interface')}:{can_kw.get('channel')}")
        if self.modbus:
            if self.cfg.modbus.plain:
                parts.append(f"Modbus TCP {self.cfg.modbus.host}:{self.modbus.port}")
            if self.modbus.tls_server is not None:
                parts.append(f"Modbus/TLS {self.modbus.tls_server.socks[0].getsockname()[0]}:{self.modbus.tls_port}")
        if self.zenoh:
            z = self.cfg.zenoh
            endpoints = z.connect if z.mode == "client" else z.listen + z.connect  # a client listens nowhere
            parts.append(f"Zenoh {z.mode} {','.join(endpoints)} prefix {self.zenoh.prefix}")
        if self.ascii is not None:
            parts.append(f"CiA 309-3 ASCII {self.ascii.section.host}:{self.ascii.port}")
        if self.health is not None and self.health.port:
            url = f"{'https' if self.health.tls else 'http'}://{self.cfg.health.host}:{self.health.port}"
            parts.append(f"health {url}/healthz" + (f", web console {url}/" if self.web else ""))
        if self.journal is not None:
            parts.append(f"journal {self.journal.path}")
        if self.command_socket.path is not None:
            parts.append(f"command socket {self.command_socket.path}")
        nodes = ", ".join(
            f"{n.name}={n.device}@{n.node_id}" + ("(sim)" if self.sim and n.name in self.sim.nodes else "")
            + (f" on {self.cfg.network_of(n.name)}" if self.cfg.networks is not None else "")
            for n in self.cfg.nodes
        )
        parts.append(f"nodes: {nodes or 'none'}")
        return " | ".join(parts)

    def status(self) -> dict[str, Any]:
        """Readiness and per-node details for /healthz. Ready while every network's bus is up,
        the PLC side serves and no thread died; ``reasons`` says why not (a network whose bus
        is down by its name); ``networks`` each network (``http.health``)."""
        modbus_up = self.modbus is None or self.modbus.server is not None
        zenoh_up = self.zenoh is None or self.zenoh.up
        dead = self.threads.failures()
        # ready: every bus and the PLC side serve; the cloud side (Zenoh) counts only for a
        # gateway without Modbus, or when our prefix is announced by another (docs/deploy.md,
        # Readiness): a probe must not take a PLC's gateway out of service because the router
        # is away. /healthz says "zenoh": false.
        northbound_up = modbus_up if self.modbus is not None else zenoh_up
        zenoh_error = self.zenoh.link.problem if self.zenoh is not None else None
        buses = bus_reasons(self.networks)
        reasons = ([] if self.started else ["starting"]) + buses
        reasons += [f"network {net.name}: another device has this gateway's pair id"
                    for net in self.networks if net.master.role == "duplicate"]  # fmt: skip
        if not northbound_up and not (self.modbus is None and zenoh_error is not None):
            reasons.append("Modbus is not serving" if self.modbus is not None else "Zenoh is down")
        if zenoh_error is not None:
            reasons.append(f"zenoh: {zenoh_error}")
        reasons += [f"thread {name} died: {why}" for name, why in dead.items()]
        first = self.networks.first
        several = {"state": self.image.bus_state, "detail": "; ".join(buses)}
        return {
            "status": "ready" if not reasons else "not-ready",
            "ready": not reasons,
            "reasons": reasons,
            "threads": {"failed": dead},
            # several networks: the worst state, and which network is not ok
            "bus": first.bus_doc() if len(self.networks) == 1 else several,
            "bus_peers": first.master.peers.doc(),
            "networks": {net.name: network_status(net) for net in self.networks},
            "modbus": modbus_up,
            "zenoh": zenoh_up,
            "uptime_s": round(time.monotonic() - self.image.started_monotonic, 1),
            "nodes": {name: health_doc(node) for name, node in self.image.nodes.items()},
        } | pair_of(first.master) | (self.modbus.watchdog_status() if self.modbus else {}) | self._journal_status()

    def _journal_status(self) -> dict[str, Any]:
        """The journal's figures and last error (a full or slow disk shows here; the gateway
        stays ready: it keeps serving without it)."""
        return {} if self.journal is None else {"journal": self.journal.status()}

    def audit_record(self, record: dict[str, Any]) -> dict[str, Any]:
        """An audit record as journaled under ``<prefix>/audit`` (the command service's audit
        sink shapes it so): with the node's network and the engineering values of a write."""
        node = record.get("node")
        network = record.get("network") or (
            self.cfg.network_of(node) if node in self.image.nodes else None
        )  # a command to "all" of one network names it itself
        return engineering_record(record | {"network": network}, self.commands)

    def overview(self) -> dict[str, Any]:
        """Gateway-wide figures for the web console's overview (counters become rates there);
        ``networks``: each network's bus, its frames, other masters, pair and nodes."""
        networks = {net.name: network_overview(net) for net in self.networks}
        first = self.networks.first
        doc: dict[str, Any] = {
            "can": networks[first.name],
            "networks": networks,
            "threads_failed": self.threads.failures(),
            "peers": first.master.peers.doc(),
            "pair": pair_of(first.master),
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
            held = FileLock.holder(self.journal.directory) if self.journal is not None else None
            if held is not None:  # the same config started twice: its journal too
                busy.also.append(StartupError("journal.path", held.directory, held.reason))
            raise busy
        if self.journal is not None:
            # first: what the gateway hears is journaled whatever the cloud does
            with startup_step("journal.path", cfg.journal.path):
                try:
                    await asyncio.to_thread(self.journal.open)
                except JournalInUse as exc:  # a second gateway on one journal.path
                    raise StartupError("journal.path", self.journal.directory, exc.reason) from None
            j = cfg.journal
            values = f"values every {j.values_ms} ms" if j.values_ms else "events only"
            log.info("journal on: %s (%s, kept %g days, at most %g MB)", self.journal.path, values, j.keep_days, j.max_mb)  # fmt: skip
            self.journal.start(self.threads)
            if self.zenoh is not None:
                self.zenoh.use_journal(self.journal)
            self.commands.audit = AuditLog(
                self.journal, audit_key(prefix_of(cfg)), self.audit_record
            )
        if self.zenoh is not None:
            z = cfg.zenoh
            key, where = ("zenoh.listen", z.listen) if z.mode == "peer" else ("zenoh.connect", z.connect)
            files = {
                f"zenoh.{section}.{k}": v
                for section in ("tls", "auth")
                for k, v in (getattr(z, section).model_dump() if getattr(z, section) else {}).items()
                if isinstance(v, str) and k.endswith(("_file", "certificate", "key"))
            }
            # before the bus; a prefix another announces leaves Zenoh closed (ZenohSession.problem)
            with startup_step(key, ", ".join(where), files):
                await self.zenoh.open()
        if self.sim is not None:
            for view, _ in self.sim.networks:
                with startup_step(view.qualify("can.channel"), view.can.channel):
                    self._start_simulated_devices(view)
        for net in self.networks:  # each network's bus, its reader and sender
            with startup_step(net.cfg.qualify("can.interface"), net.cfg.can.interface):
                await asyncio.to_thread(net.open, must_open=self.bus_must_open)
        # every listener before the master sends its first frame: a start that fails on a port
        # in use must leave the devices as they were (no NMT command, no SDO, no heartbeat)
        if self.modbus is not None:
            with startup_step("modbus.port", f"{cfg.modbus.port} on {cfg.modbus.host}"):
                await self.modbus.start()
        if self.zenoh is not None:
            await self.zenoh.start()
        if self.cfg.ascii is not None and self.cfg.ascii.enabled:
            from canopen_gateway.ascii.server import AsciiGateway

            self.ascii = AsciiGateway(self.cfg, self.image, self.commands, self.turns)
            with startup_step("ascii.port", f"{self.cfg.ascii.port} on {self.cfg.ascii.host}"):
                await self.ascii.start()
        if cfg.health.port:
            with startup_step("health.port", f"{cfg.health.port} on {cfg.health.host}"):
                await self._start_health()
            self.command_socket.facts["health_port"] = self.health.port  # `fault` finds it
        await self.command_socket.start()  # never stops a start: a warning when it cannot open
        for net in self.networks:
            await net.master.start()
        self.started = True
        if self.freeze_gc:
            gc.collect()
            gc.freeze()

    def _start_simulated_devices(self, view: Config) -> None:
        """The simulated devices' own connection to a network's bus: with ``bus_must_open``
        a bus that cannot open stops the start as the gateway's own would (``BusOpenFailed``)."""
        assert self.sim is not None
        try:
            self.sim.start_network(view)
        except Exception as exc:
            if self.bus_must_open:
                raise NetworkOpenFailed(exc, view) from exc
            raise

    async def _start_health(self) -> None:
        from canopen_gateway.http.metrics import Metrics, NodeSample
        from canopen_gateway.http.server import HealthServer

        self.metrics = Metrics()

        def on_sdo(node: str, op: str, latency_s: float, abort: int | None) -> None:
            self.metrics.sdo_request(node, op)
            self.metrics.observe_sdo_latency(node, latency_s)
            if abort is not None:
                self.metrics.sdo_abort(node, abort)

        self.networks.on_sdo(on_sdo)
        self.metrics.set_node_source(
            lambda: [
                NodeSample(n.name, int(n.health.nmt_state), n.health.alive, n.data_age_s())
                for n in self.image.nodes.values()
            ]
        )
        self.web = None
        if self.cfg.web.enabled:
            from canopen_gateway.sim.faults import FaultInjector
            from canopen_gateway.web.console import WebConsole
            from canopen_gateway.web.monitor import FrameMonitor, NetworkMonitors
            from canopen_gateway.web.views import ConsoleModel

            regmap = self.modbus.regmap if self.modbus else build_register_map(self.cfg, self.nodes)
            monitors = {  # a bus monitor per network: node ids are a network's own
                net.name: FrameMonitor(net.cfg, FrameDecoder(net.cfg, self.nodes), net.driver)
                for net in self.networks
            }
            self.web = WebConsole(
                ConsoleModel(self.cfg, self.image, self.commands, self.overview, regmap=regmap),
                faults=FaultInjector(self.sim) if self.sim is not None else None,
                turns=self.turns,
                journal=self.journal,
                monitors=NetworkMonitors(monitors),
            )
            self.web.start(asyncio.get_running_loop())
        self.health = HealthServer(
            self.cfg.health.host,
            self.cfg.health.port,
            self.status,
            self.metrics.registry,
            app=self.web,
            turns=self.turns,
            tls=self._health_tls(),
        )
        await self.health.start()
        self.metrics.set_refresh(self._copy_counters)

    def _health_tls(self) -> ssl.SSLContext | None:
        """``health.tls``'s context (its files were checked with the config; a file changed
        since is a ConfigError naming its key)."""
        tls = self.cfg.health.tls
        if tls is None:
            return None
        from canopen_gateway.http.tls import TlsFilesError, server_context

        try:
            return server_context(self.cfg.path_of(tls.cert), self.cfg.path_of(tls.key))
        except TlsFilesError as exc:
            raise ConfigError([f"{self.cfg.source}: health.tls.{k}: {m}" for k, m in exc.problems]) from None

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
        self._copy_network_counters(c)
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
            c.journal = {"written": jc.written, "dropped": jc.dropped, "removed": jc.removed,
                         "refused": jc.refused, "published_unjournaled": jc.unjournaled}
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
            c.modbus_connections, c.modbus_connections_closed = self.modbus.admission.counts()

    def _copy_network_counters(self, c: Any) -> None:
        """The metrics of each network (label ``network``): frames, errors, reopens, bus state,
        pair role, other masters."""
        for net in self.networks:
            rx, tx, name = net.driver.rx_counters, net.driver.tx_counters, net.name
            c.can_frames_in[name], c.can_frames_out[name] = rx["frames_in"], tx["frames_out"]
            c.can_bus_errors[name] = rx["bus_errors"] + tx["bus_errors"]
            c.can_bus_reopens[name] = net.driver.reopens
            c.can_bus_state[name] = BUS_STATE_CODES.get(net.state, 0)
            c.network_pair_role[name] = PAIR_ROLE_CODES.get(net.master.role, 0)
            for kind, seen in net.master.peers.other_master.items():
                c.network_other_master[(name, kind)] = seen.count

    async def stop(self) -> None:
        self.started = False
        await self.command_socket.stop()
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
        for net in self.networks:
            await net.master.stop()
        for net in self.networks:
            await asyncio.to_thread(net.driver.close)
        if self.sim is not None:
            self.sim.stop()
