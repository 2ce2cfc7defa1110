"""Modbus writes through the command service: the points a write covers (whole points only),
write protection (``read_only``, ``allowed_networks``: 0x01), the refusal of every write
while the gateway does not master the bus of its hot-standby pair (``NotActive``: 0x06), and
the write timeout (``modbus.write_timeout_s``). A write is answered when the RPDO was queued
or the device confirmed the SDO.

Imports: config, errors, modbus.protocol, modbus.reads, northbound.regmap, northbound.networks,
runtime.ratelimit, canopen.states.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable
from typing import Any

from canopen_gateway.canopen.states import NMT_BY_CODE
from canopen_gateway.config import Config
from canopen_gateway.errors import ValueOutOfRange
from canopen_gateway.modbus.protocol import ExceptionCode, ModbusError, T, from_registers
from canopen_gateway.modbus.reads import ImageReads
from canopen_gateway.northbound.networks import Networks
from canopen_gateway.northbound.regmap import TABLE_NAMES, Point, Table
from canopen_gateway.runtime.ratelimit import RateLimitedLog

log = logging.getLogger("gateway.modbus")


class ImageWrites:
    """Writes of the register map's writable points, by the command service."""

    def __init__(self, reads: ImageReads, cfg: Config, warn: RateLimitedLog):
        self.reads = reads  # a mask write reads the register first
        self.regmap = reads.regmap
        self.commands = reads.commands
        self.read_only = cfg.modbus.read_only
        self.allowed = Networks(cfg.modbus.allowed_networks)
        self.write_timeout_s = cfg.modbus.write_timeout_s
        self.warn = warn

    def write_refusal(self, peer: str | None) -> str | None:
        """Why a client at this address may not write (``read_only``, ``allowed_networks``),
        or None when it may. The server also asks it once per connection: only clients that
        may write feed the output watchdog."""
        if self.read_only:
            return "the gateway is read-only (modbus.read_only)"
        if peer is None:
            return None
        if peer not in self.allowed:
            return f"client {peer} is not in modbus.allowed_networks"
        return None

    def check_access(self, peer: str | None, unit: int, table: str, address: int, values: Any) -> None:
        """Write protection: ``read_only`` and ``allowed_networks`` (0x01, logged and audited);
        then the standby of a hot-standby pair refuses every write before it reads or checks
        a value (``NotActive``: 0x06 server device busy, the PLC retries on the active one)."""
        why = self.write_refusal(peer)
        if why is not None:
            self.warn.warning(("refused", peer, why), "Modbus write from %s refused: %s", peer, why)
            self.commands.refusals.refused(
                "modbus_write", f"unit {unit}", f"{TABLE_NAMES[table]} {address}", values, why
            )
            raise ModbusError(ExceptionCode.ILLEGAL_FUNCTION, why)
        self.commands.require_active()

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
        self.check_access(peer, unit, "hr", address, values)
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
            await self.commands.nmt(node, cmd)
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
        self.check_access(peer, unit, "co", address, values)
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
        self.check_access(peer, unit, "hr", address, {"and_mask": and_mask, "or_mask": or_mask})
        self._points_for(unit, "hr", address, 1)
        current = (await self.reads.read(unit, "hr", address, 1))[0]
        value = (current & and_mask) | (or_mask & ~and_mask & 0xFFFF)
        await self.write_registers(unit, address, [value], peer)


def _log_late_result(task: asyncio.Future[Any]) -> None:
    if task.cancelled():
        return
    exc = task.exception()
    if exc is not None:
        log.warning("Modbus write completed after its timeout with an error: %s", exc)
