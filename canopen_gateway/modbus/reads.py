"""Modbus reads of the process image: the registers and bits of a request, computed from the
image at the moment of the request (all registers of one request from one snapshot per node:
a 32-bit value read in one request comes from one PDO, never torn), the node diagnostics
(``DIAG_REGISTERS``, ``DIAG_BITS``: the health summary as register values) and the gateway's
own values. A register read served wholly from the image is compiled once per request shape
(``read_now``: a PLC repeats the same few reads); outputs are read through the command service.

Imports: commands, errors, image, modbus.protocol, modbus.watchdog, northbound.regmap,
northbound.gateway_block (the codes of the gateway block), northbound.summary.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import canopen_gateway
from canopen_gateway.commands import CommandService
from canopen_gateway.errors import BusDown, NodeNotOperational
from canopen_gateway.image import NmtState, NodeImage, ProcessImage, Quality, SignalValue
from canopen_gateway.modbus.protocol import (
    LIFECYCLE_CODES,
    ExceptionCode,
    ModbusError,
    register_encoder,
    to_registers,
)
from canopen_gateway.modbus.watchdog import OutputWatchdog
from canopen_gateway.northbound.gateway_block import (
    BUS_STATE_CODES,
    PAIR_ROLE_CODES,
    worst_bus_state,
)
from canopen_gateway.northbound.regmap import TABLE_NAMES, Point, RegisterMap, Table
from canopen_gateway.northbound.summary import NodeSummary, summarize


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


class ImageReads:
    """Registers and bits of the register map, read from the image (outputs through the
    command service)."""

    def __init__(self, regmap: RegisterMap, image: ProcessImage, commands: CommandService):
        self.regmap = regmap
        self.image = image
        self.commands = commands
        self.watchdog: OutputWatchdog | None = None  # its trips are a gateway value
        #: per node, the signals its TPDOs carry (for the quality register)
        self.process_signals: dict[str, tuple[str, ...]] = {}
        #: compiled register reads: per point, per request shape (``_read_plan``)
        self._getters: dict[Point, RegisterGetter | None] = {}
        self._plans: dict[tuple[int, str, int, int], tuple[ReadStep, ...] | None] = {}
        for p in regmap.points:
            if p.node and p.kind == "signal" and p.table == "ir":
                self.process_signals[p.node] = (*self.process_signals.get(p.node, ()), p.name)

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
            network = p.network
            return lambda snaps, sums: encode(self._gateway_value(name, network))
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
        if self.image.bus_states.get(node.network, "down") == "down":  # the node's own bus
            raise BusDown(f"CAN bus of network {node.network} is down")
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

    def _gateway_value(self, name: str, network: str | None = None) -> int:
        """Register ``name`` of the gateway block; of CAN network ``network`` when it is one
        network's (its bus state, its pair role)."""
        c = self.image.counters
        states = self.image.bus_states
        if name == "bus_state":
            state = worst_bus_state(list(states.values())) if network is None else states.get(network, "down")
            return BUS_STATE_CODES.get(state, 0)
        if name == "networks":
            return len(self.commands.networks)
        if name in c:
            return c[name] & 0xFFFFFFFF
        if name == "uptime_s":
            return int(time.monotonic() - self.image.started_monotonic)
        if name.startswith("version_"):
            parts = (canopen_gateway.__version__.split(".") + ["0", "0"])[:3]
            digits = "".join(
                ch for ch in parts[("major", "minor", "patch").index(name[8:])] if ch.isdigit()
            )
            return int(digits or 0)
        if name == "pair_role":
            role = self.commands.role if network is None else self.commands.role_of(network)
            return PAIR_ROLE_CODES.get(role, 0)
        if name == "pair_master_id":
            return self.commands.pair_master_id or 0
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
