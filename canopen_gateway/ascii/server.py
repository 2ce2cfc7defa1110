"""The CiA 309-3 ASCII gateway on TCP: one asyncio server, one ``Session`` per connection.

Each connection splits its bytes into lines (``grammar.LineSplitter``: a line over 1 KiB is
answered ERROR:101 and skipped, the connection kept) and answers them in order, one at a time,
in a task of its own; several clients are served at once. SDO and NMT requests go through the
command service, the one way south, by node name (the CANopen node id of a configured node
names it on its network, CiA 309-3's net: the gateway's networks numbered 1.. in configured
order): the same checks and the same typed errors as Modbus and Zenoh, mapped to 309-3 answers by
``protocol.answer_for_error``. The write gate (``ascii.writes``) is the session's.

With ``ascii.events: true`` every connection also gets event lines (boot-up, EMCY, heartbeat
lost / started, guarding lost) derived from the process image's health listener, on the event
loop; a client that does not read its socket gets no more event lines once 64 KiB wait for it,
and answers are still written.

A client that disconnects mid-request harms nothing: the request completes on the bus, its
answer is dropped, and the connection's task ends.

Only clients in ``ascii.allowed_networks`` (default: this machine) are served: a connection
from any other address is closed at once, counted (``refused_clients``) and logged with the
address (rate-limited). A write or NMT command refused by ``ascii.writes`` is logged and
audited (``commands.audit``).

The PLC comes first: each line takes a turn on the event loop (``turns.LoopTurns``, shared
with the web console) before it is handled, so many ASCII clients never hold a Modbus answer
up for more than one line's work; when too many clients wait for a turn, the line is answered
``ERROR:102`` (request not processed due to internal state) and the client may send it again.

Imports: asyncio, commands, config, errors, image, canopen.objref, ascii.protocol, ascii.grammar,
ascii.values, northbound.networks, runtime.ratelimit, runtime.turns. Never modbus/,
zenoh_bridge/, web/ or bus/.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from canopen_gateway import __version__
from canopen_gateway.ascii.grammar import Iec, LineSplitter, Overlong, peek_seq
from canopen_gateway.ascii.protocol import (
    EventTracker,
    HealthSample,
    NmtCommand,
    SdoDownload,
    SdoUpload,
    Session,
    answer_error,
    answer_for_error,
    answer_ok,
    answer_value,
)
from canopen_gateway.ascii.values import format_plain, format_value
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.commands import CommandService
from canopen_gateway.commands.audit import acting_as
from canopen_gateway.config import Config
from canopen_gateway.errors import GatewayError
from canopen_gateway.image import NodeImage, ProcessImage
from canopen_gateway.northbound.networks import Networks
from canopen_gateway.runtime.ratelimit import RateLimitedLog
from canopen_gateway.runtime.turns import ACCEPT_BACKLOG, LoopTurns

log = logging.getLogger("gateway.ascii")

#: lines waiting to be answered on one connection before it stops reading (back-pressure)
MAX_PENDING_LINES = 64
#: event lines are not queued for a client with more than this unsent
EVENT_BACKLOG_BYTES = 64 * 1024


class AsciiGateway:
    """``ascii:`` in the config: ``await start()`` / ``await stop()``."""

    def __init__(
        self, cfg: Config, image: ProcessImage, commands: Any, turns: LoopTurns | None = None
    ) -> None:
        assert cfg.ascii is not None
        #: turns on the event loop, shared with the other northbound clients (the PLC first;
        #: the application gives its own, standing alone it has one without a gap)
        self.turns = turns if turns is not None else LoopTurns(min_gap_s=0.0)
        self.section = cfg.ascii
        self.image = image
        self.commands: CommandService = commands
        #: CiA 309-3 net number -> the network's name, and (net, node id) -> node name
        self.nets: dict[int, str] = {k: name for k, name in enumerate(cfg.network_names(), start=1)}
        numbers = {name: k for k, name in self.nets.items()}
        self.by_id: dict[tuple[int, int], str] = {
            (numbers[cfg.network_of(name)], commands.node(name).node_id): name
            for name in commands.names()
        }
        self.server: asyncio.base_events.Server | None = None
        self.port = self.section.port
        self.connections: set[_Connection] = set()
        self.tasks: set[asyncio.Task[None]] = set()  # one per connection, until it ends
        self.tracker = EventTracker()
        self.warn = RateLimitedLog(log)
        self.requests = 0  # SDO and NMT requests performed
        self.errors = 0  # of those, answered with an error
        self.refused = 0  # writes and NMT commands refused by ``ascii.writes``
        self.allowed = Networks(self.section.allowed_networks)
        self.refused_clients = 0  # connections closed: not in ``ascii.allowed_networks``

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self.server = await loop.create_server(
            lambda: _Connection(self), self.section.host, self.section.port, backlog=ACCEPT_BACKLOG
        )
        self.port = self.server.sockets[0].getsockname()[1]
        if self.section.events:
            for node in self.image.nodes.values():
                self.tracker.update(node.node_id, _sample(node), net=self._net_of(node))
            self.image.health_listeners.append(self._on_health)
        log.info("CiA 309-3 ASCII gateway on %s:%d", self.section.host, self.port)

    async def stop(self) -> None:
        if self._on_health in self.image.health_listeners:
            self.image.health_listeners.remove(self._on_health)
        if self.server is not None:
            self.server.close()
        for conn in list(self.connections):
            conn.close()
        if self.server is not None:
            await self.server.wait_closed()
            self.server = None
        tasks = list(self.tasks)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self.connections.clear()

    # ------------------------------------------------------------------ events
    def _on_health(self, node: NodeImage, what: str) -> None:
        """On the event loop: a node's health changed or an EMCY arrived."""
        rec = node.health.last_emcy
        emcy = (rec.code, rec.register, bytes(rec.manufacturer)) if rec is not None else None
        for line in self.tracker.update(node.node_id, _sample(node), emcy, self._net_of(node)):
            for conn in list(self.connections):
                conn.send_event(line)

    def _net_of(self, node: NodeImage) -> int:
        """The CiA 309-3 net number of the node's network."""
        return next(k for k, name in self.nets.items() if name == node.network)

    def networks(self) -> dict[int, list[int]]:
        """Net number -> the node ids on that network (a session's addresses)."""
        out: dict[int, list[int]] = {k: [] for k in self.nets}
        for net, node_id in self.by_id:
            out[net].append(node_id)
        return out

    # ------------------------------------------------------------------ requests
    async def perform(self, call: SdoUpload | SdoDownload | NmtCommand) -> str:
        """One resolved request through the command service; its answer line."""
        self.requests += 1
        try:
            if isinstance(call, NmtCommand):
                if call.node_id == 0:  # every node of that network
                    await self.commands.nmt("all", call.command, self.nets[call.net])
                else:
                    await self.commands.nmt(self.by_id[call.net, call.node_id], call.command)
                return answer_ok(call.seq)
            name = self.by_id[call.net, call.node_id]
            obj = ObjRef(call.index, call.sub)
            timeout = None if call.timeout_ms is None else call.timeout_ms / 1000.0
            if isinstance(call, SdoDownload):
                await asyncio.wait_for(self.commands.sdo_write(name, obj, call.data), timeout)
                return answer_ok(call.seq)
            if call.dtype is None:
                value = await asyncio.wait_for(self.commands.sdo_read(name, obj), timeout)
                return answer_value(call.seq, format_plain(value))
            data = await asyncio.wait_for(self.commands.sdo_read(name, obj, "bytes"), timeout)
            return answer_value(call.seq, format_value(call.dtype, bytes(data)))
        except (GatewayError, TimeoutError, ValueError) as exc:
            self.errors += 1
            return answer_for_error(call.seq, exc)
        except Exception as exc:  # nothing a client sends may crash the gateway
            self.errors += 1
            self.warn.warning(("ascii_internal", type(exc).__name__), "ASCII request failed: %r", exc)
            return answer_for_error(call.seq, exc)


def _sample(node: NodeImage) -> HealthSample:
    h = node.health
    return HealthSample(h.alive, h.boot_count, h.emcy_count, h.supervision, h.loss_count)


class _Connection(asyncio.Protocol):
    """One client: lines in, answers out, in order; its own ``Session``."""

    def __init__(self, gw: AsciiGateway) -> None:
        self.gw = gw
        self.session = Session(
            [], writes=gw.section.writes, version=__version__, networks=gw.networks()
        )
        self.splitter = LineSplitter()
        self.lines: asyncio.Queue[str | Overlong | None] = asyncio.Queue()
        self.transport: asyncio.Transport | None = None
        self.task: asyncio.Task[None] | None = None
        self.paused = False
        self.writable = asyncio.Event()  # cleared while the transport's write buffer is full
        self.writable.set()
        self.peer = "?"

    # ---------------------------------------------------------------- asyncio.Protocol
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        peer = transport.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if peer else "?"
        if not peer or str(peer[0]) not in self.gw.allowed:
            self.gw.refused_clients += 1
            self.gw.warn.warning(
                "ascii_client_refused",
                "ASCII client %s refused: not in ascii.allowed_networks (%s); %d refused so far",
                peer[0] if peer else "?", self.gw.allowed, self.gw.refused_clients,
            )  # fmt: skip
            self.transport = None
            transport.close()
            return
        self.gw.connections.add(self)
        self.task = asyncio.get_running_loop().create_task(self._serve())
        self.gw.tasks.add(self.task)
        self.task.add_done_callback(self.gw.tasks.discard)
        log.debug("ASCII client %s connected", self.peer)

    def data_received(self, data: bytes) -> None:
        for item in self.splitter.feed(data):
            self.lines.put_nowait(item)
        if self.lines.qsize() >= MAX_PENDING_LINES and not self.paused and self.transport:
            self.paused = True
            self.transport.pause_reading()

    def eof_received(self) -> bool | None:
        """The client sent everything (e.g. ``nc -N``): answer what came, then close."""
        self.lines.put_nowait(None)
        return True  # keep the transport open for the answers

    def pause_writing(self) -> None:
        self.writable.clear()

    def resume_writing(self) -> None:
        self.writable.set()

    def connection_lost(self, exc: Exception | None) -> None:
        self.lines.put_nowait(None)
        self.writable.set()
        self.gw.connections.discard(self)
        self.transport = None
        log.debug("ASCII client %s disconnected", self.peer)

    # ---------------------------------------------------------------- answers
    async def _serve(self) -> None:
        """Answer the lines in order; a client that does not read its answers is not read
        either (its socket fills, then the line queue, then reading pauses)."""
        while True:
            await self.writable.wait()
            item = await self.lines.get()
            if item is None:
                break
            if await self.gw.turns.turn():
                answers = await self._answer(item)
            else:  # too many clients wait for a turn: this one may ask again
                seq = item.seq if isinstance(item, Overlong) else peek_seq(item)
                answers = [answer_error(seq, Iec.INTERNAL_STATE)]
            self._write(answers)
            if self.paused and self.lines.qsize() < MAX_PENDING_LINES // 2 and self.transport:
                self.paused = False
                self.transport.resume_reading()
        self.close()

    async def _answer(self, item: str | Overlong) -> list[str]:
        refused = self.session.refused
        try:
            result = self.session.handle(item)
        except Exception as exc:  # a bug of ours must not end the connection silently
            self.gw.warn.warning(("ascii_internal", type(exc).__name__), "ASCII line not handled: %r", exc)  # fmt: skip
            return [answer_for_error(None, exc)]
        if self.session.refused != refused:
            self.gw.refused += 1
            self.gw.warn.warning("ascii_refused", "ASCII client %s: write or NMT refused (ascii.writes is false)", self.peer)  # fmt: skip
            with acting_as(f"ascii {self.peer}"):
                line = item if isinstance(item, str) else "(line too long)"
                self.gw.commands.refusals.refused("ascii_write", "", line, None, "ascii.writes is false")
        if isinstance(result, list):
            return result
        with acting_as(f"ascii {self.peer}"):  # the audit of a write names the client
            return [await self.gw.perform(result)]

    def _write(self, lines: list[str]) -> None:
        if lines and self.transport is not None and not self.transport.is_closing():
            self.transport.write("".join(f"{line}\r\n" for line in lines).encode("ascii"))

    def send_event(self, line: str) -> None:
        t = self.transport
        if t is None or t.is_closing():
            return
        if t.get_write_buffer_size() > EVENT_BACKLOG_BYTES:
            self.gw.warn.warning("ascii_backlog", "ASCII client %s does not read: event lines dropped", self.peer)  # fmt: skip
            return
        t.write(f"{line}\r\n".encode("ascii"))

    def close(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()
