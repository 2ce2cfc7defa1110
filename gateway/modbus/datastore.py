"""The Modbus view of the process image and the command service: one request PDU in, one
response PDU out (``execute``).

Reads are computed from the process image at the moment of the request (all registers of one
request from one snapshot per node: a 32-bit value read in one request comes from one PDO,
never torn); writes go through the command service and are answered when the RPDO was queued
or the device confirmed the SDO. Write protection (``read_only``, ``allowed_networks``), the
refusal of every write while the gateway does not master the bus of its hot-standby pair
(``NotActive``: 0x06) and the write timeout live here.

Read Device Identification (function 43/14) answers from ``modbus.identity`` with the
identity objects read here from each device once per boot, through the command service.

Imports: commands, config, errors, image, modbus.identity, modbus.protocol, modbus.watchdog,
northbound.regmap, northbound.summary, ratelimit, states.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import struct
import time
from collections.abc import Awaitable, Callable, Iterator, Mapping
from typing import Any

import gateway
from gateway.commands import CommandService
from gateway.config import Config
from gateway.errors import (
    BusDown,
    GatewayError,
    NodeNotOperational,
    NotActive,
    SdoAbort,
    ValueOutOfRange,
)
from gateway.image import NmtState, NodeImage, ProcessImage, Quality, SignalValue
from gateway.modbus.identity import IDENTITY_OBJECTS, gateway_objects, node_objects
from gateway.modbus.identity import parse_request as parse_identification
from gateway.modbus.identity import respond as identification_response
from gateway.modbus.protocol import (
    COIL_ON,
    ENCAPSULATED_INTERFACE,
    LIFECYCLE_CODES,
    MASK_WRITE_REGISTER,
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING,
    READ_INPUT,
    READ_TABLE,
    WRITE_COIL,
    WRITE_COILS,
    WRITE_REGISTER,
    WRITE_REGISTERS,
    ExceptionCode,
    ModbusError,
    T,
    check_request,
    from_registers,
    pack_bits,
    register_encoder,
    to_registers,
    unpack_bits,
)
from gateway.modbus.watchdog import OutputWatchdog
from gateway.northbound.regmap import PAIR_ROLE_CODES, TABLE_NAMES, Point, RegisterMap, Table
from gateway.northbound.summary import NodeSummary, summarize
from gateway.ratelimit import RateLimitedLog
from gateway.states import NMT_BY_CODE

log = logging.getLogger("gateway.modbus")


def _nmt_register(state: NmtState) -> int:
    """The NMT state register: the CiA 301 code, 0xFFFF while unknown."""
    return 0xFFFF if state == NmtState.UNKNOWN else int(state)


#: node diagnostics in input registers (``regmap.NODE_DIAG``): the summary as register values
DIAG_REGISTERS: dict[str, Callable[[NodeSummary], int]] = {
    "quality": lambda s: int(s.quality if s.quality is not None else Quality.BAD),
    "nmt_state": lambda s: _nmt_register(s.nmt_state),
    "alive": lambda s: int(s.alive),
    "lifecycle": lambda s: LIFECYCLE_CODES.get(s.lifecycle, 0),
    "data_age_ms": lambda s: (
        0xFFFFFFFF if s.data_age_s is None else min(int(s.data_age_s * 1000), 0xFFFFFFFE)
    ),
    "last_emcy_code": lambda s: s.last_emcy.code if s.last_emcy else 0,
    "last_emcy_register": lambda s: s.last_emcy.register if s.last_emcy else 0,
    "emcy_count": lambda s: s.emcy_count & 0xFFFF,
    "loss_count": lambda s: s.loss_count & 0xFFFF,
    "link_state": lambda s: int(s.link),
    "link_fault_count": lambda s: s.link_fault_count & 0xFFFF,
    "last_sdo_abort": lambda s: s.last_sdo_abort & 0xFFFFFFFF,
    "boot_count": lambda s: s.boot_count & 0xFFFF,
    "pdo_errors": lambda s: s.pdo_errors & 0xFFFF,
}
#: node diagnostics in discrete inputs (``regmap.NODE_DIAG_BITS``)
DIAG_BITS: dict[str, Callable[[NodeSummary], bool]] = {
    "alive": lambda s: s.alive,
    "operational": lambda s: s.operational,
    "link_ok": lambda s: s.link_ok,
    "error_active": lambda s: bool(s.current_errors),
    "outputs_safe": lambda s: s.outputs == "safe",
}


#: how a point's registers are read from the image: (snapshots, summaries) of the request
RegisterGetter = Callable[[dict[str, Mapping[str, SignalValue]], dict[str, NodeSummary]], list[int]]
#: one step of a read plan: the point's getter, the slice of its registers asked for (first,
#: count) and whether that is all of them
ReadStep = tuple[RegisterGetter, int, int, bool]
#: read plans kept (request shapes); past it, a new shape is compiled for each request
PLAN_CACHE_SIZE = 1024
_MISSING: Any = object()  # not in a cache yet (None there means "an output")


# ---------------------------------------------------------------------- the datastore
class ImageDatastore:
    """Reads from the image, writes through the command service, by the register map."""

    def __init__(
        self, regmap: RegisterMap, image: ProcessImage, commands: CommandService, cfg: Config
    ):
        self.regmap = regmap
        self.image = image
        self.commands = commands
        self.read_only = cfg.modbus.read_only
        self.allowed = [ipaddress.ip_network(n, strict=False) for n in cfg.modbus.allowed_networks]
        self.write_timeout_s = cfg.modbus.write_timeout_s
        self.requests = 0
        self.by_function: dict[int, int] = {}  # requests by function code
        self.exceptions: dict[int, int] = {}
        self.warn = RateLimitedLog(log)
        self.watchdog: OutputWatchdog | None = None  # set by the server that feeds it
        self.gateway_name = cfg.gateway.name
        #: per node: (boot epoch, identity objects read from the device in that epoch)
        self._identity: dict[str, tuple[tuple[int, int], dict[str, Any]]] = {}
        #: per node, the signals its TPDOs carry (for the quality register)
        self.process_signals: dict[str, tuple[str, ...]] = {}
        #: compiled register reads: per point, per request shape (``_read_plan``)
        self._getters: dict[Point, RegisterGetter | None] = {}
        self._plans: dict[tuple[int, str, int, int], tuple[ReadStep, ...] | None] = {}
        for p in regmap.points:
            if p.node and p.kind == "signal" and p.table == "ir":
                self.process_signals[p.node] = (*self.process_signals.get(p.node, ()), p.name)

    def count_exception(self, code: ExceptionCode) -> None:
        self.exceptions[int(code)] = self.exceptions.get(int(code), 0) + 1

    # ------------------------------------------------------------------ reads
    def _points(
        self, unit: int, table: Table, address: int, count: int
    ) -> Iterator[tuple[Point, int, int]]:
        """The points of ``count`` consecutive addresses, each with the slice of its registers
        the request covers (``lo``, ``take``; bits: one each); an unmapped address raises."""
        idx = self.regmap.index.get((unit, table), {})
        a, end = address, address + count
        while a < end:
            p = idx.get(a)
            if p is None:
                raise ModbusError(
                    ExceptionCode.ILLEGAL_DATA_ADDRESS,
                    f"{TABLE_NAMES[table]} {a} of unit {unit} is not mapped",
                )
            take = 1 if table in ("di", "co") else min(p.end, end) - a
            yield p, a - p.address, take
            a += take

    @staticmethod
    def _from_image(p: Point) -> bool:
        """A value of the image (or the gateway's): read without a coroutine per point."""
        return p.kind in ("gateway", "diag", "nmt") or p.table == "ir"

    async def read(self, unit: int, table: Table, address: int, count: int) -> list[Any]:
        """Registers (ints) or bits (bools) of ``count`` consecutive addresses."""
        words: dict[tuple[str, str], Any] = {}  # a word read once per request for all its bits
        snaps: dict[str, Mapping[str, SignalValue]] = {}  # one consistent view per node
        sums: dict[str, NodeSummary] = {}  # one health summary per node
        out: list[Any] = []
        for p, lo, take in self._points(unit, table, address, count):
            if table in ("di", "co"):
                out.append(bool(await self._bit_value(p, words, snaps, sums)))
                continue
            if self._from_image(p):
                regs = self._image_regs(p, snaps, sums)
            else:
                regs = await self._reg_value(p, snaps, sums)
            out.extend(regs[lo : lo + take])
        return out

    def read_now(self, unit: int, table: Table, address: int, count: int) -> list[int] | None:
        """``read`` of registers all served from the image, at once; None when one of them
        is an output (read through the command service: ``read``)."""
        plan = self._read_plan(unit, table, address, count)
        if plan is None:
            return None
        snaps: dict[str, Mapping[str, SignalValue]] = {}  # one consistent view per node
        sums: dict[str, NodeSummary] = {}  # one health summary per node
        out: list[int] = []
        for get, lo, take, whole in plan:
            regs = get(snaps, sums)
            out.extend(regs if whole else regs[lo : lo + take])
        return out

    def _read_plan(
        self, unit: int, table: Table, address: int, count: int
    ) -> tuple[ReadStep, ...] | None:
        """The steps of a register read served from the image (None: an output among them),
        compiled once per request shape: a PLC repeats the same few reads. An unmapped address
        raises, as ``_points`` does."""
        key = (unit, table, address, count)
        plan = self._plans.get(key, _MISSING)
        if plan is not _MISSING:
            return plan
        steps: list[ReadStep] = []
        for p, lo, take in self._points(unit, table, address, count):
            get = self._getter(p)
            if get is None:
                plan = None
                break
            steps.append((get, lo, take, lo == 0 and take == p.count))
        else:
            plan = tuple(steps)
        if len(self._plans) < PLAN_CACHE_SIZE:  # a client probing every shape grows it no further
            self._plans[key] = plan
        return plan

    def _getter(self, p: Point) -> RegisterGetter | None:
        """How ``p``'s registers are read from the image (None: an output), made once per point."""
        get = self._getters.get(p, _MISSING)
        if get is _MISSING:
            get = self._make_getter(p) if self._from_image(p) else None
            self._getters[p] = get
        return get

    def _make_getter(self, p: Point) -> RegisterGetter:
        encode = register_encoder(p)
        name = p.name
        if p.kind == "gateway":
            return lambda snaps, sums: encode(self._gateway_value(name))
        node = self._node(p)
        if p.kind == "diag":
            diag = DIAG_REGISTERS.get(name)
            if diag is None:
                return lambda snaps, sums: encode(0)
            return lambda snaps, sums: encode(diag(self._summary(node, sums)))
        if p.kind == "nmt":
            return lambda snaps, sums: [_nmt_register(node.health.nmt_state)]
        return lambda snaps, sums: encode(self._servable(node, name, snaps))

    def _node(self, p: Point) -> NodeImage:
        assert p.node is not None
        return self.image.nodes[p.node]

    def _servable(
        self, node: NodeImage, name: str, snaps: dict[str, Mapping[str, SignalValue]] | None = None
    ) -> Any:
        """A process value if its quality allows serving it (stale only with serve_stale)."""
        if self.image.bus_state == "down":
            raise BusDown("CAN bus is down")
        snap: Mapping[str, SignalValue] | None = None if snaps is None else snaps.get(node.name)
        if snap is None:
            snap = node.snapshot()
            if snaps is not None:
                snaps[node.name] = snap
        s = snap[name]
        q = node.quality(s)
        if q == Quality.GOOD or (q == Quality.STALE and node.serve_stale):
            return s.value
        if s.seq == 0:
            raise NodeNotOperational(node.name, f"{name} never received")
        if not node.is_valid(name):
            raise NodeNotOperational(node.name, f"{name} flagged invalid by the device")
        raise NodeNotOperational(node.name, f"{name} is stale")

    def _image_regs(
        self,
        p: Point,
        snaps: dict[str, Mapping[str, SignalValue]] | None = None,
        sums: dict[str, NodeSummary] | None = None,
    ) -> list[int]:
        """The registers of a point served from the image (not an output): no await."""
        get = self._getter(p)
        assert get is not None, p
        return get({} if snaps is None else snaps, {} if sums is None else sums)

    async def _reg_value(
        self,
        p: Point,
        snaps: dict[str, Mapping[str, SignalValue]] | None = None,
        sums: dict[str, NodeSummary] | None = None,
    ) -> list[int]:
        if self._from_image(p):
            return self._image_regs(p, snaps, sums)
        return to_registers(await self._output_value(self._node(p).name, p.name), p)

    async def _output_value(self, node: str, name: str) -> Any:
        """A writable point: the last value sent by RPDO, else the device's value by SDO
        (from the command service's cache while younger than ``master.sdo_cache_ms``)."""
        return await self.commands.read_signal(node, name)

    async def _bit_value(
        self,
        p: Point,
        words: dict[tuple[str, str], Any],
        snaps: dict[str, Mapping[str, SignalValue]] | None = None,
        sums: dict[str, NodeSummary] | None = None,
    ) -> int:
        node = self._node(p)
        if p.kind == "diag_bit":
            return int(DIAG_BITS[p.name](self._summary(node, sums)))
        assert p.bit is not None
        key = (node.name, p.name)
        if key not in words:
            if p.table == "di" and p.transport == "pdo":
                words[key] = self._servable(node, p.name, snaps)
            else:
                words[key] = await self._output_value(node.name, p.name)
        return (int(words[key]) >> p.bit) & 1

    def _summary(self, node: NodeImage, sums: dict[str, NodeSummary] | None) -> NodeSummary:
        """The node's health summary, taken once per request."""
        s = None if sums is None else sums.get(node.name)
        if s is None:
            s = summarize(node, process=self.process_signals.get(node.name, ()))
            if sums is not None:
                sums[node.name] = s
        return s

    def _gateway_value(self, name: str) -> int:
        c = self.image.counters
        if name == "bus_state":
            return {"down": 0, "ok": 1, "error": 2}.get(self.image.bus_state, 0)
        if name in c:
            return c[name] & 0xFFFFFFFF
        if name == "uptime_s":
            return int(time.monotonic() - self.image.started_monotonic)
        if name.startswith("version_"):
            parts = (gateway.__version__.split(".") + ["0", "0"])[:3]
            digits = "".join(
                ch for ch in parts[("major", "minor", "patch").index(name[8:])] if ch.isdigit()
            )
            return int(digits or 0)
        if name == "pair_role":
            return PAIR_ROLE_CODES.get(self.commands.master.role, 0)
        if name == "watchdog_trips":
            return 0 if self.watchdog is None else sum(self.watchdog.trips.values()) & 0xFFFFFFFF
        nodes = self.image.nodes.values()
        if name == "nodes_configured":
            return len(self.image.nodes)
        if name == "nodes_alive":
            return sum(1 for n in nodes if n.health.alive)
        if name == "nodes_operational":
            return sum(1 for n in nodes if n.operational())
        return 0

    # ------------------------------------------------------------------ identification
    async def identification(self, unit: int) -> dict[int, bytes]:
        """The Read Device Identification objects of a unit (``modbus.identity``)."""
        node = self.regmap.units.get(unit)
        if node is None:
            return gateway_objects(gateway.__version__, self.gateway_name)
        info = self.commands.node(node)
        return node_objects(info.lp, node, info.node_id, await self._identity_read(node))

    async def _identity_read(self, node: str) -> dict[str, Any]:
        """1018h, 1008h, 1009h, 100Ah as read from the device once per boot (on the first
        identification request after it): objects it aborts are left out; a node that is
        not alive or does not answer gives none (the EDS / profile values are served)."""
        image = self.image.nodes[node]
        h = image.health
        epoch = (h.boot_count, h.loss_count)
        hit = self._identity.get(node)
        if hit is not None and hit[0] == epoch:
            return hit[1]
        if not h.alive:
            return {}
        read: dict[str, Any] = {}
        for key, obj in IDENTITY_OBJECTS.items():
            try:
                read[key] = await self.commands.sdo_read(node, obj)
            except SdoAbort:
                continue  # the device does not have it
            except NotActive:
                return read  # a pair's standby reads nothing by SDO: the EDS values, no warning
            except (GatewayError, TimeoutError) as exc:
                self.warn.warning(
                    ("identity", node), "identification of %s: %s not read: %s", node, obj, exc
                )
                return read  # not cached: tried again on the next request
        self._identity[node] = (epoch, read)
        return read

    # ------------------------------------------------------------------ writes
    def write_refusal(self, peer: str | None) -> str | None:
        """Why a client at this address may not write (``read_only``, ``allowed_networks``),
        or None when it may. The server also asks it once per connection: only clients that
        may write feed the output watchdog."""
        if self.read_only:
            return "the gateway is read-only (modbus.read_only)"
        if peer is None:
            return None
        try:
            ip = ipaddress.ip_address(peer.split("%", 1)[0])
        except ValueError:
            return f"client address {peer!r} not understood"
        if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        if not any(ip in net for net in self.allowed):
            return f"client {peer} is not in modbus.allowed_networks"
        return None

    def check_access(self, peer: str | None) -> None:
        """Write protection: ``read_only`` and ``allowed_networks`` (0x01, logged); then the
        standby of a hot-standby pair refuses every write before it reads or checks a value
        (``NotActive``: 0x06 server device busy, the PLC retries on the active one)."""
        why = self.write_refusal(peer)
        if why is not None:
            self.warn.warning(("refused", peer, why), "Modbus write from %s refused: %s", peer, why)
            raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, why)
        master = self.commands.master
        if not master.mastering:
            raise NotActive(
                f"this gateway is the {master.role} one of a pair: write to the active one"
            )

    async def _bounded(self, op: Awaitable[T]) -> T:
        """Wait for the device at most ``write_timeout_s``; the operation itself is never cut
        short (an SDO transfer in flight completes, its late result is only logged)."""
        task = asyncio.ensure_future(op)
        done, _ = await asyncio.wait({task}, timeout=self.write_timeout_s)
        if not done:
            task.add_done_callback(_log_late_result)
            raise TimeoutError(f"write not confirmed within {self.write_timeout_s:g} s")
        return task.result()

    def _points_for(self, unit: int, table: Table, address: int, n: int) -> list[tuple[Point, int]]:
        """Whole writable points covered by a write of ``n`` addresses: (point, index)."""
        idx = self.regmap.index.get((unit, table), {})
        out = []
        a = address
        while a < address + n:
            p = idx.get(a)
            if p is None:
                raise ModbusError(
                    ExceptionCode.ILLEGAL_DATA_ADDRESS,
                    f"{TABLE_NAMES[table]} {a} of unit {unit} is not mapped",
                )
            if p.access != "rw":
                where = f"{p.node}.{p.name}" if p.node else p.name
                raise ModbusError(ExceptionCode.ILLEGAL_DATA_ADDRESS, f"{where} is read-only")
            if p.address != a or p.end > address + n:
                raise ModbusError(
                    ExceptionCode.ILLEGAL_DATA_ADDRESS,
                    f"a write must cover all {p.count} registers {p.address}-{p.end - 1} of {p.node}.{p.name}",
                )
            out.append((p, a - address))
            a += p.count
        return out

    async def write_registers(
        self, unit: int, address: int, values: list[int], peer: str | None
    ) -> None:
        self.check_access(peer)
        points = self._points_for(unit, "hr", address, len(values))
        nmt: list[tuple[str, str]] = []
        by_node: dict[str, dict[str, Any]] = {}
        for p, start in points:
            assert p.node is not None
            regs = values[start : start + p.count]
            if p.kind == "nmt":
                cmd = NMT_BY_CODE.get(regs[0])
                if cmd is None:
                    raise ValueOutOfRange(
                        "nmt_command", regs[0], ", ".join(str(c) for c in NMT_BY_CODE)
                    )
                nmt.append((p.node, cmd))
                continue
            value = from_registers(regs, p)
            if p.type == "string":
                try:
                    value = value.decode("ascii")
                except UnicodeDecodeError:
                    raise ValueOutOfRange(p.name, value, "ASCII text") from None
            by_node.setdefault(p.node, {})[p.name] = value
        for node, cmd in nmt:
            self.commands.nmt(node, cmd)
        if by_node:
            await self._bounded(self._write_signals(by_node))

    async def _write_signals(self, by_node: dict[str, dict[str, Any]]) -> None:
        for node, vals in by_node.items():
            if len(vals) == 1:
                ((name, v),) = vals.items()
                await self.commands.write_signal(node, name, v)
            else:
                await self.commands.write_signals(node, vals)

    async def write_coils(
        self, unit: int, address: int, values: list[bool], peer: str | None
    ) -> None:
        self.check_access(peer)
        points = self._points_for(unit, "co", address, len(values))
        grouped: dict[tuple[str, str], dict[int, bool]] = {}
        transport: dict[tuple[str, str], str] = {}
        for p, start in points:
            assert p.node is not None and p.bit is not None
            grouped.setdefault((p.node, p.name), {})[p.bit] = values[start]
            transport[(p.node, p.name)] = p.transport
        await self._bounded(self._write_bits(grouped, transport))

    async def _write_bits(
        self, grouped: dict[tuple[str, str], dict[int, bool]], transport: dict[tuple[str, str], str]
    ) -> None:
        for (node, name), bits in grouped.items():
            # read-modify-write of the word (RPDO output or SDO object) by the command service
            await self.commands.write_bits(node, name, bits)

    async def mask_write(
        self, unit: int, address: int, and_mask: int, or_mask: int, peer: str | None
    ) -> None:
        """FC 22: result = (current AND and_mask) OR (or_mask AND NOT and_mask), 6.16."""
        self.check_access(peer)
        self._points_for(unit, "hr", address, 1)
        current = (await self.read(unit, "hr", address, 1))[0]
        value = (current & and_mask) | (or_mask & ~and_mask & 0xFFFF)
        await self.write_registers(unit, address, [value], peer)


def _log_late_result(task: asyncio.Future[Any]) -> None:
    if task.cancelled():
        return
    exc = task.exception()
    if exc is not None:
        log.warning("Modbus write completed after its timeout with an error: %s", exc)


# ---------------------------------------------------------------------- one request
def execute_now(store: ImageDatastore, unit: int, pdu: bytes) -> bytes | None:
    """A register read served from the image at once (no await, no task), or None when the
    request needs ``execute`` (writes, bits, identification, outputs read through the command
    service). Raises as ``execute`` does."""
    fc = pdu[0]
    if fc not in (READ_HOLDING, READ_INPUT):
        return None
    body = pdu[1:]
    code = check_request(fc, body)
    if code is not None:
        raise ModbusError(code, f"function code {fc}: malformed or unsupported request")
    if unit not in store.regmap.units:
        raise ModbusError(
            ExceptionCode.GATEWAY_PATH_UNAVAILABLE, f"unit id {unit} is not configured"
        )
    address, qty = struct.unpack(">HH", body)
    values = store.read_now(unit, READ_TABLE[fc], address, qty)
    if values is None:
        return None
    data = struct.pack(f">{len(values)}H", *values)
    return bytes((fc, len(data))) + data


async def execute(store: ImageDatastore, unit: int, pdu: bytes, peer: str | None) -> bytes:
    """Serve one request PDU; returns the response PDU (raises ModbusError / GatewayError)."""
    fc, body = pdu[0], pdu[1:]
    malformed = check_request(fc, body)
    if malformed is not None:
        raise ModbusError(malformed, f"function code {fc}: malformed or unsupported request")
    if unit not in store.regmap.units:
        raise ModbusError(
            ExceptionCode.GATEWAY_PATH_UNAVAILABLE, f"unit id {unit} is not configured"
        )
    if fc == ENCAPSULATED_INTERFACE:
        code, object_id = parse_identification(body)
        return identification_response(await store.identification(unit), code, object_id)
    if fc in READ_TABLE:
        address, qty = struct.unpack(">HH", body)
        values = await store.read(unit, READ_TABLE[fc], address, qty)
        if fc in (READ_COILS, READ_DISCRETE_INPUTS):
            data = pack_bits(values)
        else:
            data = struct.pack(f">{len(values)}H", *values)
        return bytes((fc, len(data))) + data
    if fc == WRITE_COIL:
        address, value = struct.unpack(">HH", body)
        await store.write_coils(unit, address, [value == COIL_ON], peer)
        return pdu  # the normal response is an echo of the request (6.5)
    if fc == WRITE_REGISTER:
        address, value = struct.unpack(">HH", body)
        await store.write_registers(unit, address, [value], peer)
        return pdu  # echo (6.6)
    if fc == WRITE_COILS:
        address, qty, byte_count = struct.unpack_from(">HHB", body)
        await store.write_coils(unit, address, unpack_bits(body[5:], qty), peer)
        return bytes((fc,)) + body[:4]
    if fc == WRITE_REGISTERS:
        address, qty, byte_count = struct.unpack_from(">HHB", body)
        await store.write_registers(
            unit, address, list(struct.unpack_from(f">{qty}H", body, 5)), peer
        )
        return bytes((fc,)) + body[:4]
    if fc == MASK_WRITE_REGISTER:
        address, and_mask, or_mask = struct.unpack(">HHH", body)
        await store.mask_write(unit, address, and_mask, or_mask, peer)
        return pdu  # echo (6.16)
    # READ_WRITE_REGISTERS: the write is performed before the read (6.17)
    r_addr, r_qty, w_addr, w_qty, _ = struct.unpack_from(">HHHHB", body)
    await store.write_registers(unit, w_addr, list(struct.unpack_from(f">{w_qty}H", body, 9)), peer)
    values = await store.read(unit, "hr", r_addr, r_qty)
    data = struct.pack(f">{len(values)}H", *values)
    return bytes((fc, len(data))) + data
