"""Modbus TCP server for PLCs, serving the process image through the register map.

Three layers, each testable on its own:

* ``check_request`` (pure): is a request PDU well formed for its function code? Quantity and
  length rules of the Modbus Application Protocol V1.1b3, section 6.
* ``ImageDatastore``: reads are computed from the process image at the moment of the request
  (a 32-bit value read in one request comes from one PDO, never torn); writes go through the
  command service and are answered when the RPDO was sent or the device confirmed the SDO.
* ``_Connection`` (asyncio protocol): MBAP framing (Modbus Messaging on TCP/IP Implementation
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
* 0x0A gateway path unavailable: CAN bus down; unit id not configured
* 0x0B gateway target failed to respond: node lost, never booted, not operational (and not
  ``serve_stale``), no SDO answer, write not confirmed within ``modbus.write_timeout_s``

A frame whose MBAP header is invalid (protocol id not 0, length outside 2..254) cannot be
resynchronised in a TCP stream: it is dropped and that connection closed; other clients are not
affected.

Imports: commands, config, errors, image, modbus.regmap. Never zenoh_bridge/ or bus/ directly
(the bus is reached through the command service only); no pymodbus (its server loses pipelined
requests: it clears its receive buffer on every send).
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import struct
import time
from collections.abc import Awaitable
from enum import IntEnum
from typing import Any, TypeVar

import gateway
from gateway.commands import CommandService
from gateway.config import Config
from gateway.errors import (
    BusDown,
    GatewayError,
    NodeNotOperational,
    NodeUnknown,
    ReadOnly,
    SdoAbort,
    SdoTimeout,
    Unmapped,
    ValueOutOfRange,
)
from gateway.image import LinkState, NmtState, NodeImage, ProcessImage, Quality, SignalValue
from gateway.modbus.regmap import TABLE_NAMES, Point, RegisterMap, Table, build_register_map
from gateway.ratelimit import RateLimitedLog
from gateway.states import NMT_BY_CODE

log = logging.getLogger("gateway.modbus")

T = TypeVar("T")


class ExceptionCode(IntEnum):
    """Modbus Application Protocol V1.1b3, section 7."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    GATEWAY_PATH_UNAVAILABLE = 0x0A
    GATEWAY_TARGET_FAILED_TO_RESPOND = 0x0B


# Function codes served (Modbus Application Protocol V1.1b3, 6.1-6.17)
READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING, READ_INPUT = 0x01, 0x02, 0x03, 0x04
WRITE_COIL, WRITE_REGISTER, WRITE_COILS, WRITE_REGISTERS = 0x05, 0x06, 0x0F, 0x10
MASK_WRITE_REGISTER, READ_WRITE_REGISTERS = 0x16, 0x17
READ_TABLE: dict[int, Table] = {READ_COILS: "co", READ_DISCRETE_INPUTS: "di", READ_HOLDING: "hr", READ_INPUT: "ir"}  # fmt: skip
WRITES = {WRITE_COIL, WRITE_REGISTER, WRITE_COILS, WRITE_REGISTERS, MASK_WRITE_REGISTER, READ_WRITE_REGISTERS}  # fmt: skip
SUPPORTED = {*READ_TABLE, *WRITES}

# Quantity limits (Modbus Application Protocol V1.1b3, 6.1-6.4, 6.11, 6.12, 6.17)
MAX_READ_BITS = 0x07D0
MAX_READ_REGISTERS = 0x007D
MAX_WRITE_BITS = 0x07B0
MAX_WRITE_REGISTERS = 0x007B
MAX_RW_WRITE_REGISTERS = 0x0079
COIL_ON, COIL_OFF = 0xFF00, 0x0000  # 6.5: any other value is an illegal data value

# MBAP header (Modbus TCP Implementation Guide V1.0b, 3.1.3): transaction id, protocol id 0,
# length of the unit id + PDU (a PDU has at most 253 bytes, Application Protocol 4.1)
MBAP = struct.Struct(">HHHB")
MBAP_MIN_LENGTH = 2
MBAP_MAX_LENGTH = 254

#: requests of one connection processed at once; beyond, reading from it pauses
MAX_IN_FLIGHT = 16

LIFECYCLE_CODES = {"waiting": 0, "booting": 1, "configuring": 2, "operational": 3}


class ModbusError(Exception):
    """A request answered with an exception code."""

    def __init__(self, code: ExceptionCode, why: str):
        self.code = code
        super().__init__(why)


def exception_code(exc: BaseException) -> ExceptionCode:
    """The Modbus answer to a typed error of the command service."""
    if isinstance(exc, ModbusError):
        return exc.code
    if isinstance(exc, (ValueOutOfRange, ValueError, OverflowError)):
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if isinstance(exc, (ReadOnly, Unmapped)):
        return ExceptionCode.ILLEGAL_DATA_ADDRESS
    if isinstance(exc, SdoAbort):
        return ExceptionCode.SERVER_DEVICE_FAILURE
    if isinstance(exc, BusDown):
        return ExceptionCode.GATEWAY_PATH_UNAVAILABLE
    if isinstance(exc, (NodeNotOperational, NodeUnknown, SdoTimeout, TimeoutError)):
        return ExceptionCode.GATEWAY_TARGET_FAILED_TO_RESPOND
    return ExceptionCode.SERVER_DEVICE_FAILURE


# ---------------------------------------------------------------------- request checks (pure)
def check_request(fc: int, body: bytes) -> ExceptionCode | None:
    """None if the PDU (function code + ``body``) is well formed, else the exception to answer."""
    n = len(body)
    if fc not in SUPPORTED:
        return ExceptionCode.ILLEGAL_FUNCTION
    if fc in READ_TABLE:
        if n != 4:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        address, qty = struct.unpack(">HH", body)
        limit = MAX_READ_BITS if fc in (READ_COILS, READ_DISCRETE_INPUTS) else MAX_READ_REGISTERS
        if not 1 <= qty <= limit:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return ExceptionCode.ILLEGAL_DATA_ADDRESS if address + qty > 0x10000 else None
    if fc == WRITE_COIL:
        if n != 4:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        value = struct.unpack_from(">H", body, 2)[0]
        return None if value in (COIL_ON, COIL_OFF) else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc == WRITE_REGISTER:
        return None if n == 4 else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc == MASK_WRITE_REGISTER:
        return None if n == 6 else ExceptionCode.ILLEGAL_DATA_VALUE
    if fc in (WRITE_COILS, WRITE_REGISTERS):
        if n < 5:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        address, qty, byte_count = struct.unpack_from(">HHB", body)
        if fc == WRITE_COILS:
            ok = 1 <= qty <= MAX_WRITE_BITS and byte_count == (qty + 7) // 8
        else:
            ok = 1 <= qty <= MAX_WRITE_REGISTERS and byte_count == 2 * qty
        if not ok or n != 5 + byte_count:
            return ExceptionCode.ILLEGAL_DATA_VALUE
        return ExceptionCode.ILLEGAL_DATA_ADDRESS if address + qty > 0x10000 else None
    # READ_WRITE_REGISTERS
    if n < 9:
        return ExceptionCode.ILLEGAL_DATA_VALUE
    r_addr, r_qty, w_addr, w_qty, byte_count = struct.unpack_from(">HHHHB", body)
    if not (1 <= r_qty <= MAX_READ_REGISTERS and 1 <= w_qty <= MAX_RW_WRITE_REGISTERS):
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if byte_count != 2 * w_qty or n != 9 + byte_count:
        return ExceptionCode.ILLEGAL_DATA_VALUE
    if r_addr + r_qty > 0x10000 or w_addr + w_qty > 0x10000:
        return ExceptionCode.ILLEGAL_DATA_ADDRESS
    return None


def pack_bits(bits: list[bool]) -> bytes:
    """Coils / discrete inputs: first bit in the LSB of the first byte (6.1)."""
    out = bytearray((len(bits) + 7) // 8)
    for i, b in enumerate(bits):
        if b:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(data: bytes, count: int) -> list[bool]:
    return [bool(data[i // 8] >> (i % 8) & 1) for i in range(count)]


# ---------------------------------------------------------------------- register encoding
def to_registers(value: Any, p: Point) -> list[int]:
    """A value as ``p.count`` registers: strings first character in the high byte, numbers
    with the point's word order, engineering points as float32 of raw x scale + offset."""
    t = p.type
    if t == "string":
        raw = (
            value
            if isinstance(value, (bytes, bytearray))
            else str(value).encode("ascii", "replace")
        )
        raw = bytes(raw)[: p.count * 2].ljust(p.count * 2, b"\0")
        return [(raw[i] << 8) | raw[i + 1] for i in range(0, len(raw), 2)]
    if p.engineering:
        value = float(value) * p.scale + p.offset
    if t == "float32":
        b = struct.pack(">f", float(value))
    elif t in ("int16", "uint16"):
        return [int(value) & 0xFFFF]
    elif t in ("int32", "uint32"):
        b = (int(value) & 0xFFFFFFFF).to_bytes(4, "big")
    else:  # int64 / uint64
        b = (int(value) & 0xFFFFFFFFFFFFFFFF).to_bytes(8, "big")
    words = [int.from_bytes(b[i : i + 2], "big") for i in range(0, len(b), 2)]
    if p.word_order == "little":
        words.reverse()
    return words


def from_registers(regs: list[int], p: Point) -> Any:
    """Registers written by a client back to a raw device value (inverse of to_registers)."""
    t = p.type
    if t == "string":
        raw = b"".join(r.to_bytes(2, "big") for r in regs)
        return raw.rstrip(b"\0")
    if t in ("int16", "uint16"):
        v = regs[0]
        if t == "int16" and v >= 0x8000:
            v -= 0x10000
        return v
    words = list(regs)
    if p.word_order == "little":
        words.reverse()
    b = b"".join(w.to_bytes(2, "big") for w in words)
    if t == "float32":
        f = struct.unpack(">f", b)[0]
        if p.engineering:
            # float -> raw integer: NaN / inf raise ValueError / OverflowError (0x03)
            return round((f - p.offset) / p.scale) if p.scale else 0
        return f
    return int.from_bytes(b, "big", signed=t.startswith("int"))


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
        #: per node, the signals its TPDOs carry (for the quality register)
        self.process_signals: dict[str, tuple[str, ...]] = {}
        for p in regmap.points:
            if p.node and p.kind == "signal" and p.table == "ir":
                self.process_signals[p.node] = (*self.process_signals.get(p.node, ()), p.name)

    def count_exception(self, code: ExceptionCode) -> None:
        self.exceptions[int(code)] = self.exceptions.get(int(code), 0) + 1

    # ------------------------------------------------------------------ reads
    async def read(self, unit: int, table: Table, address: int, count: int) -> list[Any]:
        """Registers (ints) or bits (bools) of ``count`` consecutive addresses."""
        idx = self.regmap.index.get((unit, table), {})
        words: dict[tuple[str, str], Any] = {}  # a word read once per request for all its bits
        snaps: dict[str, dict[str, SignalValue]] = {}  # one consistent view per node
        out: list[Any] = []
        a, end = address, address + count
        while a < end:
            p = idx.get(a)
            if p is None:
                raise ModbusError(
                    ExceptionCode.ILLEGAL_DATA_ADDRESS,
                    f"{TABLE_NAMES[table]} {a} of unit {unit} is not mapped",
                )
            if table in ("di", "co"):
                out.append(bool(await self._bit_value(p, words, snaps)))
                a += 1
                continue
            regs = await self._reg_value(p, snaps)
            lo = a - p.address
            take = min(p.end, end) - a
            out.extend(regs[lo : lo + take])
            a += take
        return out

    def _node(self, p: Point) -> NodeImage:
        assert p.node is not None
        return self.image.nodes[p.node]

    def _servable(
        self, node: NodeImage, name: str, snaps: dict[str, dict[str, SignalValue]] | None = None
    ) -> Any:
        """A process value if its quality allows serving it (stale only with serve_stale)."""
        if self.image.bus_state == "down":
            raise BusDown("CAN bus is down")
        snap = None if snaps is None else snaps.get(node.name)
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

    async def _reg_value(
        self, p: Point, snaps: dict[str, dict[str, SignalValue]] | None = None
    ) -> list[int]:
        if p.kind == "gateway":
            return to_registers(self._gateway_value(p.name), p)
        node = self._node(p)
        if p.kind == "diag":
            return to_registers(self._diag_value(node, p.name), p)
        if p.kind == "nmt":
            st = node.health.nmt_state
            return [0xFFFF if st == NmtState.UNKNOWN else int(st)]
        if p.table == "ir":
            return to_registers(self._servable(node, p.name, snaps), p)
        return to_registers(await self._output_value(node.name, p.name), p)

    async def _output_value(self, node: str, name: str) -> Any:
        """A writable point: the last value sent by RPDO, else the device's value by SDO
        (from the command service's cache while younger than ``master.sdo_cache_ms``)."""
        return await self.commands.read_signal(node, name)

    async def _bit_value(
        self,
        p: Point,
        words: dict[tuple[str, str], Any],
        snaps: dict[str, dict[str, SignalValue]] | None = None,
    ) -> int:
        node = self._node(p)
        if p.kind == "diag_bit":
            h = node.health
            return {
                "alive": h.alive,
                "operational": node.operational(),
                "link_ok": h.link in (LinkState.OK, LinkState.NOT_USED),
                "error_active": bool(h.current_errors),
            }[p.name]
        assert p.bit is not None
        key = (node.name, p.name)
        if key not in words:
            if p.table == "di" and p.transport == "pdo":
                words[key] = self._servable(node, p.name, snaps)
            else:
                words[key] = await self._output_value(node.name, p.name)
        return (int(words[key]) >> p.bit) & 1

    def _quality(self, node: NodeImage) -> Quality:
        names = self.process_signals.get(node.name, ())
        if not names:
            return Quality.GOOD if node.operational() else Quality.STALE
        now = time.monotonic()
        return max(node.quality(node.signals[n], now) for n in names)

    def _diag_value(self, node: NodeImage, name: str) -> int:
        h = node.health
        if name == "quality":
            return int(self._quality(node))
        if name == "nmt_state":
            return 0xFFFF if h.nmt_state == NmtState.UNKNOWN else int(h.nmt_state)
        if name == "alive":
            return int(h.alive)
        if name == "lifecycle":
            return LIFECYCLE_CODES.get(h.lifecycle, 0)
        if name == "data_age_ms":
            age = node.data_age_s()
            return 0xFFFFFFFF if age is None else min(int(age * 1000), 0xFFFFFFFE)
        if name == "last_emcy_code":
            return h.last_emcy.code if h.last_emcy else 0
        if name == "last_emcy_register":
            return h.last_emcy.register if h.last_emcy else 0
        if name == "emcy_count":
            return h.emcy_count & 0xFFFF
        if name == "loss_count":
            return h.loss_count & 0xFFFF
        if name == "link_state":
            return int(h.link)
        if name == "link_fault_count":
            return h.link_fault_count & 0xFFFF
        if name == "last_sdo_abort":
            return h.last_sdo_abort & 0xFFFFFFFF
        if name == "boot_count":
            return h.boot_count & 0xFFFF
        if name == "pdo_errors":
            return (node.rx.pdo_too_short + node.rx.pdo_too_long) & 0xFFFF
        return 0

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
        nodes = self.image.nodes.values()
        if name == "nodes_configured":
            return len(self.image.nodes)
        if name == "nodes_alive":
            return sum(1 for n in nodes if n.health.alive)
        if name == "nodes_operational":
            return sum(1 for n in nodes if n.operational())
        return 0

    # ------------------------------------------------------------------ writes
    def check_access(self, peer: str | None) -> None:
        """Write protection: ``read_only`` and ``allowed_networks`` (0x01, logged)."""
        why = None
        if self.read_only:
            why = "the gateway is read-only (modbus.read_only)"
        elif peer is not None:
            try:
                ip = ipaddress.ip_address(peer.split("%", 1)[0])
            except ValueError:
                why = f"client address {peer!r} not understood"
            else:
                if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
                    ip = ip.ipv4_mapped
                if not any(ip in net for net in self.allowed):
                    why = f"client {peer} is not in modbus.allowed_networks"
        if why is not None:
            self.warn.warning(("refused", peer, why), "Modbus write from %s refused: %s", peer, why)
            raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, why)

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
async def execute(store: ImageDatastore, unit: int, pdu: bytes, peer: str | None) -> bytes:
    """Serve one request PDU; returns the response PDU (raises ModbusError / GatewayError)."""
    fc, body = pdu[0], pdu[1:]
    code = check_request(fc, body)
    if code is not None:
        raise ModbusError(code, f"function code {fc}: malformed or unsupported request")
    if unit not in store.regmap.units:
        raise ModbusError(
            ExceptionCode.GATEWAY_PATH_UNAVAILABLE, f"unit id {unit} is not configured"
        )
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


# ---------------------------------------------------------------------- the connection
class _Connection(asyncio.Protocol):
    """One client: MBAP framing, requests served concurrently, answers by transaction id."""

    def __init__(self, owner: ModbusGateway):
        self.owner = owner
        self.store = owner.store
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
        log.debug("Modbus client %s connected", self.peer)

    def connection_lost(self, exc: Exception | None) -> None:
        self.owner.connections.discard(self)
        self.transport = None
        self.buf.clear()
        log.debug("Modbus client %s disconnected", self.peer)

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

    async def _serve(self, tid: int, unit: int, pdu: bytes) -> None:
        store = self.store
        store.requests += 1
        fc = pdu[0]
        store.by_function[fc] = store.by_function.get(fc, 0) + 1
        try:
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
            response = bytes(((fc | 0x80) & 0xFF, int(code)))
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(MBAP.pack(tid, 0, len(response) + 1, unit) + response)


class ModbusGateway:
    """Starts/stops the Modbus TCP server for a config."""

    def __init__(self, cfg: Config, image: ProcessImage, commands: CommandService):
        self.cfg = cfg
        self.regmap = build_register_map(cfg)
        self.store = ImageDatastore(self.regmap, image, commands, cfg)
        self.server: asyncio.Server | None = None
        self.port = cfg.modbus.port
        self.connections: set[_Connection] = set()

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self.server = await loop.create_server(
            lambda: _Connection(self),
            self.cfg.modbus.host,
            self.cfg.modbus.port,
            reuse_address=True,
        )
        if self.port == 0:
            self.port = self.server.sockets[0].getsockname()[1]
        log.info("Modbus TCP listening on %s:%d", self.cfg.modbus.host, self.port)

    async def stop(self) -> None:
        if self.server is None:
            return
        self.server.close()
        tasks = [t for c in self.connections for t in c.tasks]
        for c in list(self.connections):
            if c.transport is not None:
                c.transport.close()
        for t in tasks:
            t.cancel()
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        await self.server.wait_closed()
        self.server = None
