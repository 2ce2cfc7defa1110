"""Never lies, with a device that is not our simulator: python canopen's LocalNode built from the
SGH10 EDS answers SDO from its own dictionary, and the test sends the device's boot-up,
heartbeats and TPDOs as raw frames (SGH10 manual 4.2.2, 4.3, 4.5.3). Checked through a real
Modbus client and a real Zenoh session: values of a previous boot are never served as good,
change-only TPDOs are refreshed after NMT start, the liveliness token means "values usable",
and bit writes follow the profile."""

from __future__ import annotations

import asyncio
import struct
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import can
import canopen
import pytest
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.image import Quality
from canopen_gateway.profiles import load_profile
from tests.helpers import gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient, sample_where

NO_RESPONSE = 0x0B


class RawSgh10:
    """SGH10 node 1: python canopen's LocalNode (SDO server from the EDS, NMT slave, heartbeat
    producer once 1017h is written); boot-up and TPDOs are sent by the test."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.network = canopen.Network(self.bus)
        self.local = canopen.LocalNode(1, load_profile("sgh10").od)
        self.network.add_node(self.local)
        self.network.notifier = can.Notifier(self.bus, self.network.listeners, 0.01)
        self.nmt_seen = threading.Event()
        self.network.subscribe(0x000, self._nmt)

    def _nmt(self, cob: int, data: bytearray, ts: float) -> None:
        if data[1] in (0, 1):
            self.nmt_seen.set()

    def send(self, cob: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))

    def boot(self) -> None:
        """Power-on: boot-up message, then pre-operational (SGH10 manual 4.2.2)."""
        self.local.nmt.stop_heartbeat()
        self.nmt_seen.clear()
        self.send(0x701, b"\x00")
        self.local.nmt.state = "PRE-OPERATIONAL"

    def tpdo1(self, position: int, velocity: int = 0) -> None:
        self.send(0x181, struct.pack("<ih", position, velocity))

    def close(self) -> None:
        self.local.nmt.stop_heartbeat()
        self.network.notifier.stop()
        self.bus.shutdown()


@asynccontextmanager
async def gateway(
    node: dict[str, Any] | None = None,
) -> AsyncIterator[tuple[Gateway, RawSgh10, AsyncModbusTcpClient, ZClient]]:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10", **(node or {})}],
        simulate={"nodes": []},
        master={"probe_at_start": False, "sync_period_ms": 0},
        zenoh={"writes": True},
    )
    dev = RawSgh10(cfg.can.channel)
    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    await client.connect()
    z = ZClient(cfg.zenoh.listen)
    try:
        yield gw, dev, client, z
    finally:
        client.close()
        z.close()
        await gw.stop()
        dev.close()


def code(rr: Any) -> int | None:
    return rr.exception_code if rr.isError() else None


async def started(gw: Gateway, dev: RawSgh10) -> None:
    await asyncio.to_thread(dev.nmt_seen.wait, 5.0)
    node = gw.image.nodes["wire"]
    await wait_until(node.operational, 5, "wire operational")


async def test_values_of_a_previous_boot_are_not_served_as_good_after_a_reboot() -> None:
    async with gateway() as (gw, dev, client, z):
        prefix = gw.zenoh.prefix
        dev.boot()
        await started(gw, dev)
        dev.tpdo1(1000)
        node = gw.image.nodes["wire"]
        await wait_until(lambda: node.signals["position"].value == 1000, 3, "position 1000")
        rr = await client.read_input_registers(100, count=2, device_id=1)
        assert code(rr) is None and rr.registers == [0, 1000]
        # the device reboots: every value of the node is invalid at once
        dev.boot()
        await wait_until(lambda: node.health.boot_count == 2, 3, "second boot-up")
        rr = await client.read_input_registers(100, count=2, device_id=1)
        assert code(rr) == NO_RESPONSE
        reply = await z.get_one(f"{prefix}/wire/value/position")
        assert reply.ok and reply.body["quality"] == "stale"
        # configured and started again: still no new frame, still not good
        await started(gw, dev)
        assert node.quality(node.signals["position"]) == Quality.STALE
        rr = await client.read_input_registers(100, count=2, device_id=1)
        assert code(rr) == NO_RESPONSE
        snap = await z.get_one(f"{prefix}/wire/snapshot")
        assert snap.body["values"]["position"]["quality"] == "stale"
        # the first TPDO of the new boot: good again
        dev.tpdo1(1001)
        await wait_until(lambda: node.quality(node.signals["position"]) == Quality.GOOD, 3, "fresh")
        rr = await client.read_input_registers(100, count=2, device_id=1)
        assert code(rr) is None and rr.registers == [0, 1001]


async def test_a_change_only_tpdo_is_asked_by_rtr_after_nmt_start() -> None:
    # TPDO1 event timer 0 with transmission type 254: sent only on change
    node = {"sdo": [{"object": "0x1800:05", "value": 0}]}
    async with gateway(node) as (gw, dev, client, z):
        watch = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            dev.boot()
            seen: list[can.Message] = []

            def until_rtr(m: can.Message) -> bool:
                seen.append(m)
                return m.arbitration_id == 0x181 and m.is_remote_frame

            rtr = await asyncio.to_thread(_recv, watch, until_rtr)
            assert rtr.dlc == 6
            # on the bus, in order: NMT start of node 1, then the RTR
            starts = [m for m in seen if m.arbitration_id == 0x000 and bytes(m.data) == b"\x01\x01"]
            assert starts, "the RTR follows NMT start"
        finally:
            watch.shutdown()
        dev.tpdo1(77)  # the device answers the RTR
        img = gw.image.nodes["wire"]
        await wait_until(lambda: img.quality(img.signals["position"]) == Quality.GOOD, 3, "good")


def _recv(bus: can.BusABC, cond: Any, timeout_s: float = 5.0) -> can.Message:
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = bus.recv(0.05)
        if m is not None and cond(m):
            return m
    raise AssertionError("frame not seen")


async def test_the_liveliness_token_means_values_usable() -> None:
    async with gateway() as (gw, dev, client, z):
        prefix = gw.zenoh.prefix
        node = gw.image.nodes["wire"]
        tokens = z.watch_liveliness(f"{prefix}/alive/wire")
        dev.boot()
        await started(gw, dev)
        await sample_where(tokens, lambda s: s.kind == "PUT", what="token when operational")
        # pre-operational: the node is alive (heartbeats) but its values are not usable
        await gw.commands.nmt("wire", "preop")
        await sample_where(tokens, lambda s: s.kind == "DELETE", what="token withdrawn")
        await wait_until(lambda: node.health.nmt_state == NmtState.PRE_OPERATIONAL, 3, "pre-op")
        assert node.health.alive
        await gw.commands.nmt("wire", "start")
        await sample_where(tokens, lambda s: s.kind == "PUT", what="token again")
        assert node.operational()


@pytest.mark.parametrize(("bit", "on"), [(0, True), (2, False)])
async def test_a_bit_not_marked_writable_is_refused_and_nothing_is_written(
    bit: int, on: bool
) -> None:
    # SGH10 6000h (4.7.2.23): bit 0 not used, bit 2 scaling (always 1); only bit 3 writable
    async with gateway() as (gw, dev, client, z):
        dev.boot()
        await started(gw, dev)
        dev.local.sdo[0x6000].raw = 0x0004
        point = next(
            p for p in gw.modbus.regmap.points
            if p.node == "wire" and p.name == "operating_parameters" and p.table == "co" and p.bit == bit
        )  # fmt: skip
        rr = await client.write_coil(point.address, on, device_id=1)
        assert code(rr) == 0x02
        assert dev.local.sdo[0x6000].raw == 0x0004


async def test_bit_writes_to_an_sdo_word_keep_the_other_bits() -> None:
    async with gateway() as (gw, dev, client, z):
        prefix = gw.zenoh.prefix
        dev.boot()
        await started(gw, dev)
        dev.local.sdo[0x6000].raw = 0x0004
        # Zenoh: bits by name, read-modify-write over SDO (issue: the other bits were cleared)
        body = '{"bits": {"counting_direction_descending": true}}'
        reply = await z.get_one(f"{prefix}/wire/set/operating_parameters", body)
        assert reply.ok, reply.body
        assert dev.local.sdo[0x6000].raw == 0x000C
        # a whole word that changes a bit not writable: refused with 0x03, nothing written
        rr = await client.write_register(_hr(gw, "operating_parameters"), 0x0008, device_id=1)
        assert code(rr) == 0x03
        assert dev.local.sdo[0x6000].raw == 0x000C
        # the same word keeping bit 2: accepted
        rr = await client.write_register(_hr(gw, "operating_parameters"), 0x0004, device_id=1)
        assert code(rr) is None
        assert dev.local.sdo[0x6000].raw == 0x0004


def _hr(gw: Gateway, name: str) -> int:
    return next(
        p.address for p in gw.modbus.regmap.points
        if p.node == "wire" and p.name == name and p.table == "hr"
    )  # fmt: skip
