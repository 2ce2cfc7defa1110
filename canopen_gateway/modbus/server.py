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
(``modbus.watchdog_driver``): its timer a ``loop.call_at`` at the machine's next deadline, and a trip writes the nodes' safe outputs (``modbus.safe_outputs``) through the
command service. On the standby of a hot-standby pair it stands by (``set_mastering``): no
timer, no trip, nothing logged per period.

Modbus/TCP Security (``modbus.tls``): a second listener with TLS; each of its connections gets
the rights of its certificate's role (``modbus.security``), checked here before a request is
served: a refused request is answered 0x01 and logged once per period.

Connections (``modbus.admission``, ``modbus.listener``): the listening sockets are served by
the gateway's own accept loop; each accepted socket is admitted or closed at once by the caps
(``max_connections``, ``max_connections_per_client``; plain and TLS together), before any
protocol exists; a connection that sends nothing for ``idle_timeout_s`` is closed. Closed
connections are counted by reason and logged (rate-limited, with the client's address).

Imports: commands, config, errors, image, northbound.regmap, northbound.networks, modbus.admission,
modbus.datastore, modbus.listener, modbus.protocol, modbus.security, modbus.watchdog_driver,
device.resolved (the resolved nodes' profiles), safe_outputs. Never zenoh_bridge/, and of bus/
only the resolved nodes (the bus is reached through the command service only); no pymodbus (its server loses pipelined
requests: it clears its receive buffer on every send).
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from typing import Any

from canopen_gateway.commands import CommandService
from canopen_gateway.commands.audit import acting_as
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.errors import GatewayError
from canopen_gateway.image import ProcessImage
from canopen_gateway.modbus.admission import Admission
from canopen_gateway.modbus.datastore import ImageDatastore, execute, execute_now
from canopen_gateway.modbus.listener import AcceptLoop, bind
from canopen_gateway.modbus.protocol import (
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
from canopen_gateway.modbus.security import Access, access_of, certificate_subject, tls_context
from canopen_gateway.modbus.watchdog_driver import OutputWatchdogDriver
from canopen_gateway.northbound.networks import Networks
from canopen_gateway.northbound.regmap import build_register_map

log = logging.getLogger("gateway.modbus")


# ---------------------------------------------------------------------- the connection
class _Connection(asyncio.Protocol):
    """One client: MBAP framing, requests served concurrently, answers by transaction id."""

    def __init__(self, owner: ModbusGateway, tls: bool = False, address: str | None = None):
        self.owner = owner
        self.store = owner.store
        self.tls = tls
        self.role: str | None = None
        self.access: Access | None = None  # a TLS client's rights; None: plain TCP
        self.who = ""  # the audit's identity of this client
        self.writer = False  # may write: feeds the output watchdog
        self.transport: asyncio.Transport | None = None
        self.peer: str | None = address
        #: counted by the owner's admission (the accept loop's connections) until it is closed
        self.admitted = address is not None
        self.made = False
        self.last_rx = 0.0  # the loop's time of the last bytes received
        self._clock: Callable[[], float] = float  # the loop's clock, once connected
        self._idle: asyncio.TimerHandle | None = None
        self.buf = bytearray()
        self.in_flight = 0
        self.paused = False
        self.tasks: set[asyncio.Task[None]] = set()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        self.made = True
        self._clock = asyncio.get_running_loop().time
        info = transport.get_extra_info("peername")
        self.peer = str(info[0]) if info else self.peer
        self.owner.connections.add(self)
        self.who = f"modbus {self.peer}"
        if self.tls and self.owner.cfg.modbus.tls is not None:
            ssl_object = transport.get_extra_info("ssl_object")
            der = ssl_object.getpeercert(binary_form=True) if ssl_object is not None else None
            self.role, self.access = access_of(self.owner.cfg.modbus.tls, der)
            subject = certificate_subject(der)
            self.who += f" tls role {self.role or 'none'}" + (f" subject {subject}" if subject else "")
            log.info(
                "Modbus/TLS client %s connected (%s), role %s: %s",
                self.peer, subject or "no certificate", self.role or "none", self.access,
            )  # fmt: skip
        self._arm_idle(asyncio.get_running_loop().time())
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
        if fc in WRITES:
            self.store.writes.commands.refusals.refused("modbus_write", "", f"function {fc}", None, why)
        raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, why)

    def _arm_idle(self, now: float) -> None:
        """``modbus.idle_timeout_s``: a timer at the idle deadline, re-armed lazily (one per
        timeout, never one per request)."""
        idle_s = self.owner.idle_timeout_s
        if idle_s > 0 and self.transport is not None:
            self.last_rx = now
            loop = asyncio.get_running_loop()
            self._idle = loop.call_at(now + idle_s, self._idle_check)

    def _idle_check(self) -> None:
        self._idle = None
        if self.transport is None:
            return
        loop = asyncio.get_running_loop()
        now = loop.time()
        due = self.last_rx + self.owner.idle_timeout_s
        if self.in_flight or now < due:  # a request running, or bytes came since
            self._idle = loop.call_at(max(due, now + 1.0) if self.in_flight else due, self._idle_check)
            return
        self.owner.closed_by_gateway(self, "idle")

    def connection_lost(self, exc: Exception | None) -> None:
        self.owner.connections.discard(self)
        if self._idle is not None:
            self._idle.cancel()
            self._idle = None
        self.owner.release(self)
        self.transport = None
        self.buf.clear()
        log.debug("Modbus client %s disconnected", self.peer)
        if self.writer:
            self.owner.output_watchdog.writer_gone()

    def data_received(self, data: bytes) -> None:
        if self._idle is not None:  # the idle timer looks at it when it fires
            self.last_rx = self._clock()
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
        if pdu[0] in WRITES:
            return False  # a write is served (and refused, audited) by its task
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
            with acting_as(self.who):  # the audit names the client (and its certificate)
                self._authorise(fc)
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
        self.server: AcceptLoop | None = None  # the plain one, else the TLS one
        self.port = cfg.modbus.port
        # Modbus/TCP Security: a second listener (its context built now: a bad file stops here)
        self.tls_context = tls_context(cfg) if cfg.modbus.tls is not None else None
        self.tls_server: AcceptLoop | None = None
        self.tls_port = cfg.modbus.tls.port if cfg.modbus.tls is not None else 0
        self.connections: set[_Connection] = set()
        #: the caps on connections (``modbus.admission``); trusted: may write (the PLC)
        trusted = Networks(cfg.modbus.allowed_networks)
        self.admission = Admission(
            cfg.modbus.max_connections,
            cfg.modbus.max_connections_per_client,
            lambda address: address in trusted,
        )
        self.idle_timeout_s = cfg.modbus.idle_timeout_s
        self._opening: set[asyncio.Task[None]] = set()  # TLS handshakes, connections being made
        # the output watchdog: its machine (its trips are a gateway register) and its driver
        self.output_watchdog = OutputWatchdogDriver(cfg, nodes, commands, image)
        self.watchdog = self.output_watchdog.machine
        self.store.reads.watchdog = self.watchdog

    def set_mastering(self, mastering: bool) -> None:
        """The gateway started or stopped mastering the bus (``OutputWatchdogDriver``)."""
        self.output_watchdog.set_mastering(mastering)

    def watchdog_status(self) -> dict[str, Any]:
        """``modbus_watchdog`` of /healthz while the output watchdog is on."""
        wd = self.watchdog
        return {"modbus_watchdog": {"state": wd.state.value, "trips": dict(wd.trips)}} if wd.enabled else {}

    async def start(self) -> None:
        if self.watchdog.enabled and self.cfg.modbus.read_only:
            log.warning(
                "the Modbus output watchdog never trips: with modbus.read_only no client may "
                "write, and only clients that may write feed it"
            )
        mb = self.cfg.modbus
        if mb.plain:
            plain = AcceptLoop(
                await bind(mb.host, mb.port), lambda s, a: self._accepted(s, a, False), "Modbus TCP"
            )
            self.server = plain
            plain.start()
            self.output_watchdog.serving = True
            self.port = plain.port
            log.info("Modbus TCP listening on %s:%d", mb.host, self.port)
        tls = mb.tls
        if tls is not None:
            host = tls.host or mb.host
            try:
                socks = await bind(host, tls.port)
            except BaseException:
                await self.stop()
                raise
            self.tls_server = AcceptLoop(socks, lambda s, a: self._accepted(s, a, True), "Modbus/TLS")
            self.tls_server.start()
            self.tls_port = self.tls_server.port
            if self.server is None:
                self.server = self.tls_server
                self.output_watchdog.serving = True
            log.info("Modbus/TCP Security (TLS) listening on %s:%d", host, self.tls_port)

    # ------------------------------------------------------------------ connections
    def _accepted(self, sock: socket.socket, address: str, tls: bool) -> None:
        """A socket the accept loop took: admitted (a protocol is made for it) or closed."""
        decision = self.admission.decide(address)
        if decision in ("per_client", "total"):
            sock.close()
            self._refused(address, decision)
            return
        if decision == "evict":
            victims = [c for c in self.connections if c.admitted and c.peer is not None
                       and not self.admission.trusted(c.peer)]  # fmt: skip
            if victims:
                self.closed_by_gateway(min(victims, key=lambda c: c.last_rx), "evicted")
        self.admission.opened(address)
        conn = _Connection(self, tls=tls, address=address)
        task = asyncio.get_running_loop().create_task(self._connect(conn, sock))
        self._opening.add(task)
        task.add_done_callback(self._opening.discard)

    async def _connect(self, conn: _Connection, sock: socket.socket) -> None:
        """The transport of an admitted socket (the TLS handshake first on the TLS port)."""
        loop = asyncio.get_running_loop()
        try:
            await loop.connect_accepted_socket(
                lambda: conn, sock, ssl=self.tls_context if conn.tls else None
            )
        except (OSError, asyncio.CancelledError, Exception) as exc:  # noqa: BLE001 - a failed handshake
            if not conn.made:
                self.release(conn)
                sock.close()
            if conn.tls and not isinstance(exc, asyncio.CancelledError):
                self.store.warn.warning(
                    ("tls_handshake", conn.peer),
                    "Modbus/TLS client %s refused: %s", conn.peer, exc,
                )  # fmt: skip
            if isinstance(exc, asyncio.CancelledError):
                raise

    def _refused(self, address: str, reason: str) -> None:
        n = self.admission.count(reason)
        if reason == "per_client":
            why = (f"{self.admission.max_per_client} connections from that address are open "
                   "(modbus.max_connections_per_client)")  # fmt: skip
        else:
            why = f"{self.admission.max_total} connections are open (modbus.max_connections)"
        self.store.warn.warning(
            ("connection_refused", reason),
            "Modbus connection from %s closed at once: %s; %d refused so far",
            address, why, n,
        )  # fmt: skip

    def closed_by_gateway(self, conn: _Connection, reason: str) -> None:
        """Close a connection for ``reason`` (idle, evicted): counted, logged (rate-limited)."""
        n = self.admission.count(reason)
        self.release(conn)  # its place is free now, not when the loop reports it closed
        words = {
            "idle": f"it sent nothing for {self.idle_timeout_s:g} s (modbus.idle_timeout_s)",
            "evicted": "a client in modbus.allowed_networks needed its place (modbus.max_connections)",
        }[reason]
        self.store.warn.warning(
            ("connection_closed", reason),
            "Modbus connection from %s closed: %s; %d so far", conn.peer, words, n,
        )  # fmt: skip
        if conn.transport is not None:
            conn.transport.close()

    def release(self, conn: _Connection) -> None:
        """The connection no longer counts against the caps (once)."""
        if conn.admitted and conn.peer is not None:
            conn.admitted = False
            self.admission.closed(conn.peer)

    async def stop(self) -> None:
        if self.server is None and self.tls_server is None:
            return
        self.output_watchdog.stop()
        for listener in (self.server, self.tls_server):
            if listener is not None:
                listener.close()
        for t in list(self._opening):
            t.cancel()
        tasks = [t for c in self.connections for t in c.tasks]
        for c in list(self.connections):
            if c.transport is not None:
                c.transport.close()
        for t in tasks:
            t.cancel()
        if tasks or self._opening:
            await asyncio.gather(*tasks, *self._opening, return_exceptions=True)
        await asyncio.sleep(0)  # the transports' connection_lost callbacks run
        self.server = None
        self.tls_server = None
