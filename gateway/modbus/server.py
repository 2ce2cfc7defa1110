"""Modbus TCP server for PLCs, serving the process image through the register map.

Three layers, each testable on its own, each in its module:

* ``modbus.protocol.check_request`` (pure): is a request PDU well formed for its function code? Quantity and
  length rules of the Modbus Application Protocol V1.1b3, section 6.
* ``modbus.datastore.execute`` on the roles of an ``ImageDatastore``: reads are computed from the process image at the moment of the request
  (a 32-bit value read in one request comes from one PDO, never torn); writes go through the
  command service and are answered when the RPDO was sent or the device confirmed the SDO.
* ``_Connection`` (here, an asyncio protocol): MBAP framing (Modbus Messaging on TCP/IP Implementation
  Guide V1.0b, 3.1.3), several requests of one client in flight at once (answered by their
  transaction id), back-pressure, and no crash on garbage.

Exception codes a client receives (``docs/modbus.md`` has the details):

* 0x01 illegal function: unsupported function code; any write while ``modbus.read_only`` or
  from a client outside ``modbus.allowed_networks`` (logged)
* 0x02 illegal data address: unmapped address, write to a read-only point, a write covering part
  of a multi-register value
* 0x03 illegal data value: malformed request (length, quantity, byte count, coil value), value
  out of range or of the wrong type (e.g. non-ASCII text)
* 0x04 server device failure: the device aborted the SDO transfer (the abort code is in the
  node's ``last_sdo_abort`` input registers 12-13)
* 0x06 server device busy: any write, and a read by SDO, to a gateway of a hot-standby pair
  that does not master the bus (``NotActive``)
* 0x0A gateway path unavailable: CAN bus down; unit id not configured
* 0x0B gateway target failed to respond: node lost, never booted, not operational (and not
  ``serve_stale``), no SDO answer, write not confirmed within ``modbus.write_timeout_s``

A frame whose MBAP header is invalid (protocol id not 0, length outside 2..254) cannot be
resynchronised in a TCP stream: it is dropped and that connection closed; other clients are not
affected.

The output watchdog (``modbus.watchdog_ms``, ``watchdog_on_disconnect``) is fed here, by
clients allowed to write only (decided once per connection: ``ImageWrites.write_refusal``
for ``read_only`` and ``allowed_networks``, and on TLS a role with ``write`` access): their
requests, their connections and disconnections. Its machine is
``modbus.watchdog.OutputWatchdog``, driven beside the server by ``OutputWatchdogDriver``
(here): its timer a ``loop.call_at`` at the machine's next deadline, and a trip writes the nodes' safe outputs (``modbus.safe_outputs``) through the
command service. On the standby of a hot-standby pair it stands by (``set_mastering``): no
timer, no trip, nothing logged per period.

Modbus/TCP Security (``modbus.tls``): a second listener with TLS; each of its connections gets
the rights of its certificate's role (``modbus.security``), checked here before a request is
served: a refused request is answered 0x01 and logged once per period.

Imports: commands, config, errors, image, northbound.regmap, modbus.datastore, modbus.protocol,
modbus.security, modbus.watchdog,
device.resolved (the resolved nodes' profiles), safe_outputs. Never zenoh_bridge/, and of bus/
only the resolved nodes (the bus is reached through the command service only); no pymodbus (its server loses pipelined
requests: it clears its receive buffer on every send).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from gateway.commands import CommandService
from gateway.commands.audit import acting_as
from gateway.config import Config
from gateway.device.resolved import ResolvedNode
from gateway.errors import GatewayError
from gateway.image import ProcessImage
from gateway.modbus.datastore import ImageDatastore, execute, execute_now
from gateway.modbus.protocol import (
    MAX_IN_FLIGHT,
    MBAP,
    MBAP_MAX_LENGTH,
    MBAP_MIN_LENGTH,
    WRITES,
    ExceptionCode,
    ModbusError,
    exception_code,
    read_range,
)
from gateway.modbus.safe_outputs import safe_outputs
from gateway.modbus.security import Access, access_of, tls_context
from gateway.modbus.watchdog import TIMEOUT, OutputWatchdog, WatchdogState
from gateway.northbound.regmap import build_register_map

log = logging.getLogger("gateway.modbus")


# ---------------------------------------------------------------------- the connection
class _Connection(asyncio.Protocol):
    """One client: MBAP framing, requests served concurrently, answers by transaction id."""

    def __init__(self, owner: ModbusGateway, tls: bool = False):
        self.owner = owner
        self.store = owner.store
        self.tls = tls
        self.role: str | None = None
        self.access: Access | None = None  # a TLS client's rights; None: plain TCP
        self.writer = False  # may write: feeds the output watchdog
        self.transport: asyncio.Transport | None = None
        self.peer: str | None = None
        self.buf = bytearray()
        self.in_flight = 0
        self.paused = False
        self.tasks: set[asyncio.Task[None]] = set()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        info = transport.get_extra_info("peername")
        self.peer = str(info[0]) if info else None
        self.owner.connections.add(self)
        if self.tls and self.owner.cfg.modbus.tls is not None:
            ssl_object = transport.get_extra_info("ssl_object")
            der = ssl_object.getpeercert(binary_form=True) if ssl_object is not None else None
            self.role, self.access = access_of(self.owner.cfg.modbus.tls, der)
            log.info(
                "Modbus/TLS client %s connected, role %s: %s",
                self.peer, self.role or "none", self.access,
            )  # fmt: skip
        self.writer = (
            self.access in (None, "write") and self.store.writes.write_refusal(self.peer) is None
        )
        if self.writer:
            self.owner.output_watchdog.writer_connected()
        log.debug(
            "Modbus client %s connected (%s)",
            self.peer,
            "may write" if self.writer else "reads only",
        )

    def _authorise(self, fc: int) -> None:
        """A TLS client's role: ``read`` may not write, ``none`` may do nothing (0x01)."""
        access = self.access
        if access is None or access == "write" or (access == "read" and fc not in WRITES):
            return
        what = "a write" if fc in WRITES else "a request"
        why = f"{what} (function {fc}) needs a role with write access; role {self.role or 'none'} has {access}"
        self.store.warn.warning(
            ("role", self.peer, self.role, access),
            "Modbus/TLS client %s refused: %s",
            self.peer,
            why,
        )
        raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, why)

    def connection_lost(self, exc: Exception | None) -> None:
        self.owner.connections.discard(self)
        self.transport = None
        self.buf.clear()
        log.debug("Modbus client %s disconnected", self.peer)
        if self.writer:
            self.owner.output_watchdog.writer_gone()

    def data_received(self, data: bytes) -> None:
        self.buf += data
        self._parse()

    def _parse(self) -> None:
        buf = self.buf
        while self.in_flight < MAX_IN_FLIGHT and len(buf) >= MBAP.size:
            tid, pid, length, unit = MBAP.unpack_from(buf)
            if pid != 0 or not MBAP_MIN_LENGTH <= length <= MBAP_MAX_LENGTH:
                self.store.warn.warning(
                    ("mbap", self.peer),
                    "Modbus client %s sent an invalid MBAP header (protocol id %d, length %d); "
                    "connection closed",
                    self.peer,
                    pid,
                    length,
                )
                buf.clear()
                if self.transport is not None:
                    self.transport.close()
                return
            size = 6 + length
            if len(buf) < size:
                break
            pdu = bytes(buf[MBAP.size : size])
            del buf[:size]
            if not self.in_flight and self._serve_now(tid, unit, pdu):
                continue  # a read of the image: answered at once, no task
            self.in_flight += 1
            task = asyncio.get_running_loop().create_task(self._serve(tid, unit, pdu))
            self.tasks.add(task)
            task.add_done_callback(self._done)
        if self.in_flight >= MAX_IN_FLIGHT and not self.paused and self.transport is not None:
            self.paused = True
            self.transport.pause_reading()

    def _done(self, task: asyncio.Task[None]) -> None:
        self.tasks.discard(task)
        self.in_flight -= 1
        if self.transport is None:
            return
        if self.paused and self.in_flight < MAX_IN_FLIGHT:
            self.paused = False
            self.transport.resume_reading()
        self._parse()

    def _serve_now(self, tid: int, unit: int, pdu: bytes) -> bool:
        """Answer a register read served from the image right here (with nothing else in
        flight, so answers keep the order of the requests); False: ``_serve`` it in a task."""
        store = self.store
        try:
            self._authorise(pdu[0])
            response = execute_now(store, unit, pdu)
        except Exception:  # noqa: BLE001 - the task path answers it with its exception code
            return False
        if response is None:
            return False
        store.requests += 1
        store.by_function[pdu[0]] = store.by_function.get(pdu[0], 0) + 1
        self._feed_watchdog()
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(MBAP.pack(tid, 0, len(response) + 1, unit) + response)
        return True

    def _feed_watchdog(self) -> None:
        """A request of a client that may write, while it is connected (an answer after the
        client went is no sign of life), feeds the output watchdog."""
        if self.writer and self.transport is not None:
            self.owner.output_watchdog.request_seen()

    async def _serve(self, tid: int, unit: int, pdu: bytes) -> None:
        store = self.store
        store.requests += 1
        self._feed_watchdog()
        fc = pdu[0]
        store.by_function[fc] = store.by_function.get(fc, 0) + 1
        try:
            self._authorise(fc)
            role = f" tls role {self.role or 'none'}" if self.access is not None else ""
            with acting_as(f"modbus {self.peer}{role}"):  # the audit of a write names the client
                response = await execute(store, unit, pdu, self.peer)
        except Exception as exc:  # noqa: BLE001 - every failure becomes an exception response
            code = exception_code(exc)
            store.count_exception(code)
            if fc in WRITES:
                if not (isinstance(exc, ModbusError) and code == ExceptionCode.ILLEGAL_FUNCTION):
                    store.warn.warning(
                        ("write", self.peer, unit, fc, int(code)),
                        "Modbus write (function %d) from %s to unit %d failed with 0x%02X: %s",
                        fc, self.peer, unit, int(code), exc,
                    )  # fmt: skip
            elif not isinstance(exc, (ModbusError, GatewayError, ValueError)):
                store.warn.warning(("error", type(exc).__name__), "error serving Modbus: %r", exc)
            else:  # a refused read: in words once a period per client, unit, function and code
                words = code.name.lower().replace("_", " ")
                store.warn.warning(
                    ("read", self.peer, unit, fc, int(code)),
                    "Modbus read from %s refused: unit %d, function %d, %s: 0x%02X (%s): %s",
                    self.peer, unit, fc, read_range(fc, pdu), int(code), words, exc,
                )  # fmt: skip
            response = bytes(((fc | 0x80) & 0xFF, int(code)))
        self._feed_watchdog()  # again when answered: a slow write is no silence
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(MBAP.pack(tid, 0, len(response) + 1, unit) + response)


class ModbusGateway:
    """Starts/stops the Modbus TCP server for a config."""

    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        commands: CommandService,
        nodes: dict[str, ResolvedNode],
    ):
        self.cfg = cfg
        self.commands = commands
        self.regmap = build_register_map(cfg, nodes)
        self.store = ImageDatastore(self.regmap, image, commands, cfg)
        self.server: asyncio.Server | None = None  # the plain one, else the TLS one
        self.port = cfg.modbus.port
        # Modbus/TCP Security: a second listener (its context built now: a bad file stops here)
        self.tls_context = tls_context(cfg) if cfg.modbus.tls is not None else None
        self.tls_server: asyncio.Server | None = None
        self.tls_port = cfg.modbus.tls.port if cfg.modbus.tls is not None else 0
        self.connections: set[_Connection] = set()
        # the output watchdog: its machine (its trips are a gateway register) and its driver
        self.output_watchdog = OutputWatchdogDriver(cfg, nodes, commands, image)
        self.watchdog = self.output_watchdog.machine
        self.store.reads.watchdog = self.watchdog

    def set_mastering(self, mastering: bool) -> None:
        """The gateway started or stopped mastering the bus (``OutputWatchdogDriver``)."""
        self.output_watchdog.set_mastering(mastering)

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        if self.watchdog.enabled and self.cfg.modbus.read_only:
            log.warning(
                "the Modbus output watchdog never trips: with modbus.read_only no client may "
                "write, and only clients that may write feed it"
            )
        if self.cfg.modbus.plain:
            self.server = await loop.create_server(
                lambda: _Connection(self),
                self.cfg.modbus.host,
                self.cfg.modbus.port,
                reuse_address=True,
            )
            self.output_watchdog.serving = True
            if self.port == 0:
                self.port = self.server.sockets[0].getsockname()[1]
            log.info("Modbus TCP listening on %s:%d", self.cfg.modbus.host, self.port)
        tls = self.cfg.modbus.tls
        if tls is not None:
            host = tls.host or self.cfg.modbus.host
            self.tls_server = await loop.create_server(
                lambda: _Connection(self, tls=True),
                host,
                tls.port,
                ssl=self.tls_context,
                reuse_address=True,
            )
            self.tls_port = self.tls_server.sockets[0].getsockname()[1]
            if self.server is None:
                self.server = self.tls_server
                self.output_watchdog.serving = True
            log.info("Modbus/TCP Security (TLS) listening on %s:%d", host, self.tls_port)

    async def stop(self) -> None:
        if self.server is None:
            return
        self.output_watchdog.stop()
        self.server.close()
        if self.tls_server is not None and self.tls_server is not self.server:
            self.tls_server.close()
        tasks = [t for c in self.connections for t in c.tasks]
        for c in list(self.connections):
            if c.transport is not None:
                c.transport.close()
        for t in tasks:
            t.cancel()
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        await self.server.wait_closed()
        if self.tls_server is not None and self.tls_server is not self.server:
            await self.tls_server.wait_closed()
        self.server = None
        self.tls_server = None


# ---------------------------------------------------------------------- the output watchdog
class OutputWatchdogDriver:
    """Drives the output watchdog's machine (``modbus.watchdog.OutputWatchdog``) on the event
    loop, beside the server: the connections of clients that may write report their requests,
    connections and disconnections here; its timer is a ``loop.call_at`` at the machine's next
    deadline (armed only while the server serves); a trip writes the nodes' safe outputs
    (``modbus.safe_outputs``) through the command service."""

    def __init__(
        self, cfg: Config, nodes: dict[str, ResolvedNode], commands: CommandService,
        image: ProcessImage,
    ) -> None:
        self.commands = commands
        self.image = image  # its output records: the writes made or heard (a pair's take-over)
        self.watchdog_ms = cfg.modbus.watchdog_ms
        self.machine = OutputWatchdog(
            cfg.modbus.watchdog_ms / 1000.0, cfg.modbus.watchdog_on_disconnect
        )
        self.safe_plan: dict[str, dict[str, Any]] = {}
        if self.machine.enabled:
            for n in cfg.nodes:
                values = safe_outputs(nodes[n.name].lp, n)
                if values:
                    self.safe_plan[n.name] = values
        self.last_safe: dict[str, str] = {}  # per node: "safe" or why not, at the last trip
        #: the server listens: the timer may be armed, a client's disconnection counts
        self.serving = False
        self._timer: asyncio.TimerHandle | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    def writer_connected(self) -> None:
        self.machine.on_writer_connect(asyncio.get_running_loop().time())

    def request_seen(self) -> None:
        """Every request of a client that may write (any unit, any function, any outcome)
        feeds the watchdog."""
        wd = self.machine
        if not wd.enabled:
            return
        wd.on_request(asyncio.get_running_loop().time())
        if self._timer is None:
            self._schedule()

    def set_mastering(self, mastering: bool) -> None:
        """The gateway started or stopped mastering the bus (a hot-standby pair's role; the
        app calls it at start and at every role change). On the standby the watchdog is
        STANDBY (commands refuse: no safe outputs to write, no timer); when the gateway becomes
        active it counts from the PLC's last sign: a request of a client that may write to
        this gateway, or the last write to an output made or heard on the bus (the nodes'
        output records, on the bus clock: the loop's monotonic clock); none: as at start."""
        if mastering == (self.machine.state is not WatchdogState.STANDBY):
            return
        written = [n.outputs.monotonic for n in self.image.nodes.values() if n.outputs.seq]
        self.machine.on_mastering(mastering, max(written, default=None))
        self._cancel_timer()
        self._schedule()  # armed from the PLC's last sign: due now, or later

    def writer_gone(self) -> None:
        if not self.serving:
            return  # the server stops: its clients did not go away
        reason = self.machine.on_writer_disconnect(asyncio.get_running_loop().time())
        if reason is not None:
            self._trip(reason)

    def stop(self) -> None:
        """The server stops: no timer, and its clients' disconnections are no trip."""
        self.serving = False
        self._cancel_timer()

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _schedule(self) -> None:
        deadline = self.machine.next_deadline()
        if deadline is not None and self.serving:
            self._timer = asyncio.get_running_loop().call_at(deadline, self._tick)

    def _tick(self) -> None:
        self._timer = None
        reason = self.machine.tick(asyncio.get_running_loop().time())
        if reason is not None:
            self._trip(reason)
        else:
            self._schedule()  # a request came since: the deadline moved

    def _trip(self, reason: str) -> None:
        ms = self.watchdog_ms
        if reason == TIMEOUT:
            why = f"no request of a client allowed to write for {ms} ms"
        elif ms:
            why = f"the last client allowed to write disconnected; no request of one for {ms} ms"
        else:
            why = "the last client allowed to write disconnected"
        log.warning(
            "Modbus output watchdog tripped (%s): writing the safe outputs of %s",
            why,
            ", ".join(self.safe_plan) or "no node (none has a safe value)",
        )
        task = asyncio.get_running_loop().create_task(self._write_safe())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _write_safe(self) -> None:
        self.last_safe = await self.commands.write_safe_outputs(self.safe_plan)
