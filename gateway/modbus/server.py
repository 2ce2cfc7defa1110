"""Modbus TCP server for PLCs, serving the process image through the register map.

pymodbus does the protocol (framing, function codes, malformed frames); every data access
lands in ``ImageDatastore``, which answers from the process image at the moment of the request
(so a 32-bit value read in one request always comes from one PDO) and turns writes into calls of
the command service. Errors are the PLC's to act on:

* 0x01 illegal function: writes refused by ``read_only`` or by ``allowed_networks``
* 0x02 illegal address: unmapped address, write to a read-only point, partial write of a point
* 0x03 illegal value: out of range, not a valid value for the type (e.g. non-ASCII text)
* 0x04 device failure: SDO abort (the code is in the node's ``last_sdo_abort`` registers)
* 0x0A gateway path unavailable: CAN bus down
* 0x0B gateway target failed to respond: node lost, never booted, not operational, SDO timeout

Imports: pymodbus, commands, errors, image, modbus.regmap. Never zenoh_bridge/ or bus/ directly
(the bus is reached through the command service only).
"""

from __future__ import annotations

import contextvars
import ipaddress
import logging
import struct
import time
from collections.abc import Callable
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice

import gateway
from gateway.commands import CommandService
from gateway.config import Config
from gateway.errors import (
    BusDown,
    NodeNotOperational,
    NodeUnknown,
    ReadOnly,
    SdoAbort,
    SdoTimeout,
    Unmapped,
    ValueOutOfRange,
)
from gateway.image import LinkState, NmtState, NodeImage, ProcessImage, Quality
from gateway.modbus.regmap import Point, RegisterMap, build_register_map

log = logging.getLogger("gateway.modbus")

_peer: contextvars.ContextVar[str | None] = contextvars.ContextVar("modbus_peer", default=None)

READ_FC = {1: "co", 2: "di", 3: "hr", 4: "ir"}
WRITE_FC = {5: "co", 15: "co", 6: "hr", 16: "hr", 22: "hr", 23: "hr"}
LIFECYCLE_CODES = {"waiting": 0, "booting": 1, "configuring": 2, "operational": 3, "lost": 4}
NMT_WRITE = {1: "start", 2: "stop", 128: "preop", 129: "reset", 130: "reset-comm"}


class _Refused(Exception):
    def __init__(self, code: ExcCodes, why: str):
        self.code = code
        super().__init__(why)


# ---------------------------------------------------------------------- register encoding
def to_registers(value: Any, p: Point) -> list[int]:
    t = p.type
    if t == "string":
        raw = value if isinstance(value, (bytes, bytearray)) else str(value).encode("ascii", "replace")
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
            return round((f - p.offset) / p.scale) if p.scale else 0
        return f
    return int.from_bytes(b, "big", signed=t.startswith("int"))


class ImageDatastore:
    """Duck-typed pymodbus datastore: answers from the image, writes via the command service."""

    def __init__(
        self,
        regmap: RegisterMap,
        image: ProcessImage,
        commands: CommandService,
        cfg: Config,
        on_exception: Callable[[int], None] | None = None,
    ):
        self.regmap = regmap
        self.image = image
        self.commands = commands
        self.read_only = cfg.modbus.read_only
        self.allowed = [ipaddress.ip_network(n, strict=False) for n in cfg.modbus.allowed_networks]
        self.on_exception = on_exception
        self.requests = 0
        self.exceptions: dict[int, int] = {}

    def device_ids(self) -> list[int]:
        return list(self.regmap.units)

    def _count_exc(self, code: ExcCodes) -> ExcCodes:
        self.exceptions[int(code)] = self.exceptions.get(int(code), 0) + 1
        if self.on_exception is not None:
            self.on_exception(int(code))
        return code

    # ------------------------------------------------------------------ reads
    async def async_getValues(
        self, device_id: int, func_code: int, address: int, count: int = 1
    ) -> list[int] | list[bool] | ExcCodes:
        self.requests += 1
        if device_id not in self.regmap.units:
            raise NoSuchIdException(f"unit {device_id}")
        table = READ_FC.get(func_code) or WRITE_FC.get(func_code)
        if table is None:
            return self._count_exc(ExcCodes.ILLEGAL_FUNCTION)
        try:
            return await self._read(device_id, table, address, count)  # type: ignore[arg-type]
        except _Refused as exc:
            return self._count_exc(exc.code)
        except Exception as exc:  # noqa: BLE001
            return self._count_exc(self._map_error(exc))

    async def _read(self, unit: int, table: str, address: int, count: int) -> list[Any]:
        idx = self.regmap.index.get((unit, table), {})  # type: ignore[arg-type]
        out: list[Any] = []
        a = address
        end = address + count
        while a < end:
            p = idx.get(a)
            if p is None:
                raise _Refused(ExcCodes.ILLEGAL_ADDRESS, f"address {a} unmapped")
            if table in ("di", "co"):
                out.append(bool(await self._bit_value(p)))
                a += 1
                continue
            regs = await self._reg_value(p)
            lo = a - p.address
            take = min(p.end, end) - a
            out.extend(regs[lo : lo + take])
            a += take
        return out

    def _node(self, p: Point) -> NodeImage:
        assert p.node is not None
        return self.image.nodes[p.node]

    def _servable(self, node: NodeImage, sig_name: str) -> Any:
        if self.image.bus_state == "down" and not node.serve_stale:
            raise BusDown("CAN bus is down")
        s = node.signals[sig_name]
        q = node.quality(s)
        if q == Quality.GOOD or (node.serve_stale and s.seq):
            return s.value
        if q == Quality.BAD and s.seq:
            raise NodeNotOperational(node.name, f"{sig_name} is not valid")
        raise NodeNotOperational(node.name, "no current data")

    async def _reg_value(self, p: Point) -> list[int]:
        if p.kind == "gateway":
            return to_registers(self._gateway_value(p.name), p)
        node = self._node(p)
        if p.kind == "diag":
            return to_registers(self._diag_value(node, p.name), p)
        if p.kind == "nmt":
            st = node.health.nmt_state
            return [0xFFFF if st == NmtState.UNKNOWN else int(st)]
        if p.table == "ir":
            return to_registers(self._servable(node, p.name), p)
        # holding register: last value sent (RPDO) or read through SDO
        rt = self.commands.node(node.name)
        if p.transport == "pdo" and p.name in rt.rpdo_by_signal:
            return to_registers(self.commands.current_output(rt, p.name), p)
        value = await self.commands.read_signal(node.name, p.name)
        return to_registers(value, p)

    async def _bit_value(self, p: Point) -> int:
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
        if p.table == "co":
            rt = self.commands.node(node.name)
            v = self.commands.current_output(rt, p.name)
            if v is None:
                v = await self.commands.read_signal(node.name, p.name)
        else:
            v = self._servable(node, p.name)
        return (int(v) >> p.bit) & 1

    def _diag_value(self, node: NodeImage, name: str) -> int:
        h = node.health
        if name == "quality":
            if not node.operational():
                return int(Quality.STALE) if any(s.seq for s in node.signals.values()) else int(Quality.BAD)
            return int(Quality.GOOD)
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
            return h.last_sdo_abort
        if name == "boot_count":
            return h.boot_count & 0xFFFF
        if name == "pdo_errors":
            return h.pdo_errors & 0xFFFF
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
            return int(parts[("major", "minor", "patch").index(name[8:])])
        nodes = self.image.nodes.values()
        if name == "nodes_configured":
            return len(self.image.nodes)
        if name == "nodes_alive":
            return sum(1 for n in nodes if n.health.alive)
        if name == "nodes_operational":
            return sum(1 for n in nodes if n.operational())
        return 0

    # ------------------------------------------------------------------ writes
    async def async_setValues(
        self, device_id: int, func_code: int, address: int, values: list[int] | list[bool]
    ) -> ExcCodes | None:
        self.requests += 1
        if device_id not in self.regmap.units:
            raise NoSuchIdException(f"unit {device_id}")
        table = WRITE_FC.get(func_code)
        if table is None:
            return self._count_exc(ExcCodes.ILLEGAL_FUNCTION)
        peer = _peer.get()
        try:
            self._check_access(peer)
            if table == "hr":
                await self._write_registers(device_id, address, [int(v) for v in values])
            else:
                await self._write_coils(device_id, address, [bool(v) for v in values])
        except _Refused as exc:
            log.warning("Modbus write from %s to unit %d address %d refused: %s", peer, device_id, address, exc)
            return self._count_exc(exc.code)
        except Exception as exc:  # noqa: BLE001
            code = self._map_error(exc)
            log.warning("Modbus write from %s to unit %d address %d failed: %s", peer, device_id, address, exc)
            return self._count_exc(code)
        return None

    def _check_access(self, peer: str | None) -> None:
        if self.read_only:
            raise _Refused(ExcCodes.ILLEGAL_FUNCTION, "gateway is read-only (modbus.read_only)")
        if peer is None:
            return
        try:
            ip = ipaddress.ip_address(peer)
        except ValueError:
            raise _Refused(ExcCodes.ILLEGAL_FUNCTION, f"unknown peer {peer}") from None
        if not any(ip in net for net in self.allowed):
            raise _Refused(ExcCodes.ILLEGAL_FUNCTION, f"client {peer} not in modbus.allowed_networks")

    def _points_for(self, unit: int, table: str, address: int, n: int) -> list[tuple[Point, int, int]]:
        """Whole points covered by a write of n addresses: (point, start in values, length)."""
        idx = self.regmap.index.get((unit, table), {})  # type: ignore[arg-type]
        out = []
        a = address
        while a < address + n:
            p = idx.get(a)
            if p is None:
                raise _Refused(ExcCodes.ILLEGAL_ADDRESS, f"address {a} unmapped")
            if p.access != "rw":
                raise _Refused(ExcCodes.ILLEGAL_ADDRESS, f"{p.node}.{p.name} is read-only")
            if table == "hr" and (p.address != a or p.end > address + n):
                raise _Refused(ExcCodes.ILLEGAL_ADDRESS, f"write must cover all {p.count} registers of {p.name} at {p.address}")
            out.append((p, a - address, p.count))
            a += p.count
        return out

    async def _write_registers(self, unit: int, address: int, values: list[int]) -> None:
        points = self._points_for(unit, "hr", address, len(values))
        by_node: dict[str, dict[str, Any]] = {}
        for p, start, cnt in points:
            regs = values[start : start + cnt]
            if p.kind == "nmt":
                cmd = NMT_WRITE.get(regs[0])
                if cmd is None:
                    raise ValueOutOfRange("nmt_command", regs[0], "1, 2, 128, 129 or 130")
                assert p.node is not None
                self.commands.nmt(p.node, cmd)
                continue
            value = from_registers(regs, p)
            if p.type == "string":
                try:
                    value = value.decode("ascii")
                except UnicodeDecodeError:
                    raise ValueOutOfRange(p.name, value, "ASCII text only") from None
            assert p.node is not None
            by_node.setdefault(p.node, {})[p.name] = value
        for node, vals in by_node.items():
            if len(vals) == 1:
                (name, v), = vals.items()
                await self.commands.write_signal(node, name, v)
            else:
                await self.commands.write_signals(node, vals)

    async def _write_coils(self, unit: int, address: int, values: list[bool]) -> None:
        points = self._points_for(unit, "co", address, len(values))
        grouped: dict[tuple[str, str], dict[int, bool]] = {}
        for p, start, _ in points:
            assert p.node is not None and p.bit is not None
            grouped.setdefault((p.node, p.name), {})[p.bit] = values[start]
        for (node, name), bits in grouped.items():
            await self.commands.write_bits(node, name, bits)

    @staticmethod
    def _map_error(exc: Exception) -> ExcCodes:
        if isinstance(exc, (ValueOutOfRange, ValueError)):
            return ExcCodes.ILLEGAL_VALUE
        if isinstance(exc, (ReadOnly, Unmapped)):
            return ExcCodes.ILLEGAL_ADDRESS
        if isinstance(exc, SdoAbort):
            return ExcCodes.DEVICE_FAILURE
        if isinstance(exc, BusDown):
            return ExcCodes.GATEWAY_PATH_UNAVIABLE
        if isinstance(exc, (NodeNotOperational, NodeUnknown, SdoTimeout)):
            return ExcCodes.GATEWAY_NO_RESPONSE
        log.error("unexpected error serving Modbus: %r", exc)
        return ExcCodes.DEVICE_FAILURE


class _Handler(ServerRequestHandler):
    async def handle_request(self) -> None:
        peer = None
        if self.transport is not None:
            info = self.transport.get_extra_info("peername")
            if info:
                peer = info[0]
        _peer.set(peer)
        await super().handle_request()


class _Server(ModbusTcpServer):
    def callback_new_connection(self) -> ServerRequestHandler:
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class ModbusGateway:
    """Starts/stops the Modbus TCP server for a config."""

    def __init__(self, cfg: Config, image: ProcessImage, commands: CommandService):
        self.cfg = cfg
        self.regmap = build_register_map(cfg)
        self.store = ImageDatastore(self.regmap, image, commands, cfg)
        self.server: _Server | None = None
        self.port = cfg.modbus.port

    async def start(self) -> None:
        placeholder = SimDevice(id=0, simdata=[SimData(0, datatype=DataType.REGISTERS)])
        self.server = _Server(placeholder, address=(self.cfg.modbus.host, self.cfg.modbus.port))
        self.server.context = self.store  # type: ignore[assignment]
        await self.server.serve_forever(background=True)
        if self.server.transport is not None and self.port == 0:
            sock = self.server.transport.sockets[0]  # type: ignore[attr-defined]
            self.port = sock.getsockname()[1]

    async def stop(self) -> None:
        if self.server is not None:
            await self.server.shutdown()
            self.server = None
