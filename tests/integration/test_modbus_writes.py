"""Writing over Modbus TCP reaches the devices: AP05 set points and control word as RPDOs
(checked in the simulated AP05's objects 0x5F16:01/03 and 0x5F0C), configuration objects by SDO
download, single bits by coils, the NMT register, mask write and read/write multiple."""

from __future__ import annotations

import struct
from contextlib import AbstractAsyncContextManager
from typing import Any

from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.northbound.regmap import Point
from tests.helpers import make_config, modbus_gateway, operational, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}

# AP05 unit 125, holding registers (docs/modbus.md)
SET_POINT1, CHARS1, SET_POINT2, CHARS2, CONTROL_WORD = 100, 102, 103, 105, 106
GUARDING_BIT = 0x0100  # AP05 manual 5.5.5: control bit 8 is the gateway's, not the PLC's


def running(
    nodes: list[dict[str, Any]], **sections: Any
) -> AbstractAsyncContextManager[tuple[Gateway, AsyncModbusTcpClient]]:
    cfg = make_config(nodes, zenoh={"enabled": False}, **sections)
    return modbus_gateway(cfg, [(operational(n["name"]), f"{n['name']} operational") for n in nodes])


def find(gw: Gateway, node: str, name: str, kind: str = "signal") -> Point:
    return next(
        p for p in gw.modbus.regmap.points if (p.node, p.name, p.kind) == (node, name, kind)
    )


def obj(gw: Gateway, node: str, index: int, sub: int) -> Any:
    sim = gw.sim.nodes[node]
    return gw.sim.runner.call(lambda now: sim.get(index, sub))


def u32(value: int) -> int:
    return value & 0xFFFFFFFF


async def test_set_points_written_as_two_registers_reach_the_ap05_by_rpdo() -> None:
    async with running([DISPLAY]) as (gw, client):
        rr = await client.write_registers(SET_POINT1, [0xFFFF, 0xCFC7], device_id=125)  # -12345
        assert not rr.isError(), rr
        await wait_until(lambda: u32(obj(gw, "display", 0x5F16, 3)) == u32(-12345), 2, "5F16h:03")
        rr = await client.write_registers(SET_POINT2, [0x0001, 0x86A0], device_id=125)  # 100000
        assert not rr.isError(), rr
        await wait_until(lambda: obj(gw, "display", 0x5F16, 1) == 100000, 2, "5F16h:01")
        back = await client.read_holding_registers(SET_POINT1, count=5, device_id=125)
        assert back.registers == [0xFFFF, 0xCFC7, 0, 0x0001, 0x86A0], "last values sent"


async def test_set_point_characters_and_control_word_in_one_request_are_one_rpdo() -> None:
    async with running([DISPLAY]) as (gw, client):
        sent: list[bytes] = []
        gw.image.pdo_listeners.append(
            lambda node, cob, data: sent.append(data) if cob >> 8 in (2, 3) else None
        )  # RPDOs sent (2xxh, 3xxh)
        # set point2 300, characters "AB", control word bit 9 (set point2 valid): 4 registers
        rr = await client.write_registers(SET_POINT2, [0, 300, 0x4142, 0x0200], device_id=125)
        assert not rr.isError(), rr
        frame = sent[-1]
        assert frame[:6] == bytes([0x2C, 0x01, 0, 0, ord("A"), ord("B")])
        assert int.from_bytes(frame[6:8], "little") & ~GUARDING_BIT == 0x0200
        await wait_until(lambda: obj(gw, "display", 0x5F16, 1) == 300, 2, "5F16h:01")
        assert obj(gw, "display", 0x5F0C, 0) & ~GUARDING_BIT == 0x0200
        # the AP05 acknowledges a valid set point2 in status bit 10 (manual 5.3.3 table 28)
        await wait_until(
            lambda: gw.image.nodes["display"].signals["status_word"].value & 0x0400,
            2,
            "status word bit 10 set point2 valid",
        )


async def test_a_control_word_coil_sets_one_bit_and_the_status_word_follows() -> None:
    async with running([DISPLAY]) as (gw, client):
        coil = find(gw, "display", "control_word", "bit").address  # bit 0 of 5F0Ch
        rr = await client.write_coil(coil + 2, True, device_id=125)  # set point1 valid
        assert not rr.isError(), rr
        await wait_until(lambda: obj(gw, "display", 0x5F0C, 0) & 0x0004, 2, "5F0Ch bit 2")
        status_bit2 = find(gw, "display", "status_word", "bit").address + 2
        await wait_until(
            lambda: gw.image.nodes["display"].signals["status_word"].value & 0x0004, 2, "echo"
        )
        di = await client.read_discrete_inputs(status_bit2, count=1, device_id=125)
        assert di.bits[0] is True
        coils = await client.read_coils(coil, count=16, device_id=125)
        assert coils.bits[2] is True
        rr = await client.write_coils(coil + 2, [False], device_id=125)
        assert not rr.isError(), rr
        await wait_until(lambda: not obj(gw, "display", 0x5F0C, 0) & 0x0004, 2, "bit 2 cleared")


async def test_configuration_writes_are_answered_after_the_sdo_download_was_confirmed() -> None:
    async with running([DISPLAY]) as (gw, client):
        window = find(gw, "display", "target_window1").address
        rr = await client.write_register(window, 250, device_id=125)
        assert not rr.isError(), rr
        assert obj(gw, "display", 0x5F10, 0) == 250, "in the device when the response came"
        offset = find(gw, "display", "application_offset").address  # int16
        rr = await client.write_register(offset, 0xFE0C, device_id=125)  # -500
        assert not rr.isError(), rr
        assert obj(gw, "display", 0x2001, 0) == -500
        back = await client.read_holding_registers(offset, count=1, device_id=125)
        assert back.registers == [0xFE0C]
        pin = find(gw, "display", "configuration_pin").address  # uint32, 2 registers
        rr = await client.write_registers(pin, [0x0001, 0x1170], device_id=125)
        assert not rr.isError(), rr
        assert obj(gw, "display", 0x2005, 3) == 70000


async def test_a_coil_of_a_parameter_word_is_a_read_modify_write_by_sdo() -> None:
    async with running([DISPLAY]) as (gw, client):
        before = obj(gw, "display", 0x6000, 0)
        assert before & 0x0004, "scaling bit set at the factory"
        coil = find(gw, "display", "operating_parameters", "bit").address
        rr = await client.write_coil(coil + 0, True, device_id=125)  # counter_clockwise
        assert not rr.isError(), rr
        assert obj(gw, "display", 0x6000, 0) == before | 0x0001, "other bits kept"
        bits = await client.read_coils(coil, count=3, device_id=125)
        assert bits.bits[:3] == [True, False, True]


async def test_nmt_register_commands_the_node_and_reads_its_state() -> None:
    async with running([WIRE]) as (gw, client):
        node = gw.image.nodes["wire"]
        assert (await client.read_holding_registers(0, count=1, device_id=1)).registers == [5]
        rr = await client.write_register(0, 128, device_id=1)  # pre-operational
        assert not rr.isError(), rr
        await wait_until(lambda: node.health.nmt_state == 127, 3, "pre-operational")
        assert (await client.read_holding_registers(0, count=1, device_id=1)).registers == [127]
        rr = await client.write_register(0, 1, device_id=1)  # start
        assert not rr.isError(), rr
        await wait_until(node.operational, 3, "operational again")


async def test_mask_write_changes_only_the_masked_bits_of_the_control_word() -> None:
    """(current AND and_mask) OR (or_mask AND NOT and_mask): clear bit 2, set bit 4."""
    async with running([DISPLAY]) as (gw, client):
        await client.write_register(CONTROL_WORD, 0x0204, device_id=125)
        rr = await client.mask_write_register(
            address=CONTROL_WORD, and_mask=0xFFEB, or_mask=0x0010, device_id=125
        )
        assert not rr.isError(), rr
        await wait_until(
            lambda: obj(gw, "display", 0x5F0C, 0) & ~GUARDING_BIT == 0x0210, 2, "0x0210"
        )


async def test_read_write_multiple_writes_first_then_reads() -> None:
    async with running([DISPLAY]) as (gw, client):
        rr = await client.readwrite_registers(
            read_address=SET_POINT2, read_count=2, write_address=SET_POINT2, values=[0, 777],
            device_id=125,
        )  # fmt: skip
        assert rr.registers == [0, 777]
        await wait_until(lambda: obj(gw, "display", 0x5F16, 1) == 777, 2, "5F16h:01")


async def test_an_as_float_point_is_written_in_engineering_units_and_rounded_to_raw() -> None:
    wire = {**WIRE, "signals": {"work_area_1_low_limit": {"as_float": True}}}
    async with running([wire]) as (gw, client):
        limit = find(gw, "wire", "work_area_1_low_limit")
        regs = list(struct.unpack(">HH", struct.pack(">f", -50.52)))  # mm, step 0.1 mm
        rr = await client.write_registers(limit.address, regs, device_id=1)
        assert not rr.isError(), rr
        assert obj(gw, "wire", 0x6401, 1) == -505
        back = await client.read_holding_registers(limit.address, count=2, device_id=1)
        value = struct.unpack(">f", struct.pack(">HH", *back.registers))[0]
        assert abs(value - (-50.5)) < 1e-4


async def test_reserved_control_bits_are_refused_by_coil_and_by_whole_word_writes() -> None:
    """AP05 manual 004 table 27: control bits 0, 1 and 5 are reserved, always 0."""
    async with running([DISPLAY]) as (gw, client):
        sent: list[bytes] = []
        gw.image.pdo_listeners.append(
            lambda node, cob, data: sent.append(data) if cob >> 8 in (2, 3) else None
        )  # RPDOs sent
        coil = find(gw, "display", "control_word", "bit").address  # bit 0 of 5F0Ch
        for bit in (0, 1, 5):
            rr = await client.write_coil(coil + bit, True, device_id=125)
            assert rr.isError() and rr.exception_code == 0x02, bit
        rr = await client.write_register(CONTROL_WORD, 0x0201, device_id=125)
        assert rr.isError() and rr.exception_code == 0x03
        assert all(int.from_bytes(f[6:8], "little") & 0x0023 == 0 for f in sent)
        # writable bits and the gateway's own guarding bit (ignored) are accepted
        rr = await client.write_register(CONTROL_WORD, 0x0200 | GUARDING_BIT, device_id=125)
        assert not rr.isError(), rr
        await wait_until(lambda: obj(gw, "display", 0x5F0C, 0) & 0x0200, 2, "bit 9 set")
        assert obj(gw, "display", 0x5F0C, 0) & 0x0023 == 0
