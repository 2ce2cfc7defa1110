"""Reading the gateway over Modbus TCP with a real pymodbus client, simulated devices on a
virtual CAN bus: every register type, both word orders, strings, bits, diagnostics, the gateway
unit, never-torn 32-bit values, several clients at once."""

from __future__ import annotations

import asyncio
import struct
import time
from contextlib import AbstractAsyncContextManager
from typing import Any

import can
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.image import LinkState
from tests.helpers import make_config, modbus_gateway, wait_until, with_position

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}  # SGH10: position int32, velocity int16
ROTARY = {"name": "rotary", "node_id": 3, "profile": "posi_plus"}  # POSI+: position uint32
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}  # AP05: status word bits

HOLD = {
    "wire": {"kind": "hold", "min": -5000, "max": 5000, "hold": -1234},
    "rotary": {"kind": "hold", "min": 0, "max": 100000, "hold": 70000},
    "display": {"kind": "hold", "min": -1000, "max": 1000, "hold": -7},
}


def running(
    nodes: list[dict[str, Any]], motion: dict[str, Any] | None = None, **sections: Any
) -> AbstractAsyncContextManager[tuple[Gateway, AsyncModbusTcpClient]]:
    """A gateway with simulated nodes, operational and with process data, and a connected client."""
    cfg = make_config(
        nodes,
        zenoh={"enabled": False},
        simulate={"nodes": "all", "motion": motion or {}},
        **sections,
    )
    return modbus_gateway(
        cfg, [(with_position(n["name"]), f"{n['name']} operational with a position") for n in nodes]
    )


def s32(regs: list[int], little: bool = False) -> int:
    hi, lo = (regs[1], regs[0]) if little else (regs[0], regs[1])
    return struct.unpack(">i", struct.pack(">HH", hi, lo))[0]


def f32(regs: list[int]) -> float:
    return struct.unpack(">f", struct.pack(">HH", *regs))[0]


async def test_process_values_of_each_register_type_are_the_devices_values() -> None:
    async with running([WIRE, ROTARY, DISPLAY], HOLD) as (gw, client):
        wire = (await client.read_input_registers(100, count=3, device_id=1)).registers
        assert wire[:2] == [0xFFFF, 0xFB2E], "int32 -1234, high word first"
        assert s32(wire[:2]) == -1234 == gw.image.nodes["wire"].signals["position"].value
        assert wire[2] == 0, "int16 velocity of a held axis"
        rotary = (await client.read_input_registers(100, count=2, device_id=3)).registers
        assert rotary == [0x0001, 0x1170], "uint32 70000"
        display = (await client.read_input_registers(100, count=3, device_id=125)).registers
        assert s32(display[:2]) == -7
        status = gw.image.nodes["display"].signals["status_word"].value
        assert display[2] & ~0x100 == status & ~0x100, "uint16 status word (bit 8 toggles)"


async def test_word_order_is_configurable_for_the_gateway_and_per_point() -> None:
    nodes = [
        WIRE,
        {**ROTARY, "signals": {"position": {"word_order": "big"}}},
    ]
    async with running(nodes, HOLD, modbus={"word_order": "little"}) as (_, client):
        wire = (await client.read_input_registers(100, count=2, device_id=1)).registers
        assert wire == [0xFB2E, 0xFFFF], "gateway default little: low word first"
        assert s32(wire, little=True) == -1234
        rotary = (await client.read_input_registers(100, count=2, device_id=3)).registers
        assert rotary == [0x0001, 0x1170], "point override big: high word first"


async def test_as_float_serves_the_engineering_value_as_float32() -> None:
    nodes = [{**WIRE, "signals": {"position": {"as_float": True}}}]
    async with running(nodes, HOLD) as (_, client):
        regs = (await client.read_input_registers(100, count=2, device_id=1)).registers
        assert abs(f32(regs) - (-123.4)) < 1e-4, "raw -1234 x 0.1 mm"


async def test_text_objects_are_read_by_sdo_first_character_in_the_high_byte() -> None:
    async with running([WIRE], HOLD) as (gw, client):
        name = next(p for p in gw.modbus.regmap.points if p.name == "device_name")
        rr = await client.read_holding_registers(name.address, count=3, device_id=1)
        assert rr.registers == [0x5347, 0x4831, 0x3000]  # "SGH10" + NUL (1008h)
        raw = b"".join(r.to_bytes(2, "big") for r in rr.registers).rstrip(b"\0")
        assert raw.decode("ascii") == gw.sim.nodes["wire"].get(0x1008, 0)


async def test_configuration_objects_are_read_from_the_device_by_sdo() -> None:
    async with running([DISPLAY], HOLD) as (gw, client):
        sim = gw.sim.nodes["display"]
        gw.sim.runner.call(lambda now: sim.set(0x5F10, 0, 321))
        window = next(p for p in gw.modbus.regmap.points if p.name == "target_window1")
        rr = await client.read_holding_registers(window.address, count=1, device_id=125)
        assert rr.registers == [321]


async def test_bits_of_a_status_word_are_discrete_inputs_at_start_plus_bit() -> None:
    async with running([DISPLAY], HOLD) as (gw, client):
        node = gw.image.nodes["display"]
        # guarding bit link on: status bit 8 echoes the control bit the gateway toggles
        await wait_until(lambda: node.signals["status_word"].value & 0x100, 3, "status bit 8 set")
        word = (await client.read_input_registers(102, count=1, device_id=125)).registers[0]
        bits = (await client.read_discrete_inputs(100, count=16, device_id=125)).bits[:16]
        assert bits == [bool(word >> b & 1) for b in range(16)]


async def test_bits_of_a_parameter_word_are_read_by_sdo_once_per_request() -> None:
    async with running([WIRE], HOLD) as (gw, client):
        status = next(
            p for p in gw.modbus.regmap.points if p.name == "operating_status" and p.kind == "bit"
        )
        sim = gw.sim.nodes["wire"]
        expected = gw.sim.runner.call(lambda now: sim.get(0x6500, 0))
        spy = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            bits = (await client.read_discrete_inputs(status.address, count=16, device_id=1)).bits
            frames = []
            while (msg := spy.recv(timeout=0)) is not None:
                frames.append(msg)
        finally:
            spy.shutdown()
        assert bits[:16] == [bool(expected >> b & 1) for b in range(16)]
        assert bits[2], "6500h bit 2: scaling enabled (factory 0004h)"
        uploads = [
            m
            for m in frames
            if m.arbitration_id == 0x601 and bytes(m.data[:4]) == b"\x40\x00\x65\x00"
        ]
        assert len(uploads) == 1, "one SDO upload of 6500h for the 16 bits"


async def test_node_diagnostics_and_gateway_unit_describe_health_and_bus() -> None:
    async with running([WIRE, DISPLAY], HOLD) as (gw, client):
        display = gw.image.nodes["display"]
        await wait_until(lambda: display.health.link == LinkState.OK, 3, "guarding-bit link ok")
        diag = (await client.read_input_registers(0, count=16, device_id=125)).registers
        assert diag[0] == 0, "quality good"
        assert diag[1] == 5, "NMT operational"
        assert diag[2] == 1, "alive"
        assert diag[3] == 3, "lifecycle operational"
        assert (diag[4] << 16 | diag[5]) < 2000, "data age in ms"
        assert diag[10] == 1, "guarding-bit link ok"
        assert diag[12:14] == [0, 0], "no SDO abort"
        wire_link = (await client.read_input_registers(10, count=1, device_id=1)).registers
        assert wire_link == [0], "SGH10 has no guarding-bit link"
        flags = (await client.read_discrete_inputs(0, count=4, device_id=125)).bits[:4]
        assert flags == [True, True, True, False]
        gw_regs = (await client.read_input_registers(0, count=19, device_id=247)).registers
        assert gw_regs[0] == 1, "bus ok"
        assert (gw_regs[1] << 16 | gw_regs[2]) > 0, "frames in"
        assert gw_regs[13:16] == [0, 1, 0], "version 0.1.0"
        assert gw_regs[16:19] == [2, 2, 2], "configured, alive, operational"


async def test_a_32_bit_value_read_in_one_request_is_never_torn() -> None:
    """The ramp crosses zero, where both words change at once (FFFF FFFF -> 0000 0000): each
    value read must lie between the image values seen before and after the request."""
    motion = {"wire": {"kind": "ramp", "min": -8000, "max": 30000, "speed": 20000}}
    async with running([WIRE], motion) as (gw, client):
        assert gw.image.nodes["wire"].signals["position"].value < 0, "the ramp must start below zero"
        seen = 0
        deadline = time.monotonic() + 10  # a bound on a stuck ramp, not a measure of speed
        while gw.image.nodes["wire"].signals["position"].value < 2000 and time.monotonic() < deadline:
            before = gw.image.nodes["wire"].signals["position"].value
            rr = await client.read_input_registers(100, count=2, device_id=1)
            after = gw.image.nodes["wire"].signals["position"].value
            if rr.isError():  # a starved machine may see the node stale for a moment: said so
                assert rr.exception_code == 0x0B, rr
                continue
            assert before <= s32(rr.registers) <= after, (before, rr.registers, after)
            seen += 1
        assert gw.image.nodes["wire"].signals["position"].value >= 2000, "the ramp did not cross zero in time"
        assert seen > 10


async def test_several_clients_read_at_once_and_each_gets_its_answers() -> None:
    async with running([WIRE, DISPLAY], HOLD) as (gw, _):

        async def poll(unit: int, address: int, expected: list[int]) -> int:
            c = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
            await c.connect()
            try:
                for _ in range(40):
                    rr = await c.read_input_registers(address, count=len(expected), device_id=unit)
                    assert rr.registers == expected
                return 40
            finally:
                c.close()

        done = await asyncio.gather(
            poll(1, 100, [0xFFFF, 0xFB2E]),
            poll(125, 100, [0xFFFF, 0xFFF9]),
            poll(1, 1, [5]),
            poll(125, 2, [1]),
            poll(247, 16, [2]),
        )
        assert done == [40] * 5
        assert gw.modbus.store.requests >= 200


async def test_flat_layout_serves_every_node_in_one_unit_at_k_times_stride() -> None:
    flat = {"layout": "flat", "flat_unit_id": 1, "flat_stride": 300}
    async with running([WIRE, DISPLAY], HOLD, modbus=flat) as (_, client):
        gateway_block = await client.read_input_registers(0, count=1, device_id=1)
        assert gateway_block.registers == [1], "bus ok at address 0"
        wire = await client.read_input_registers(300 + 100, count=2, device_id=1)
        assert wire.registers == [0xFFFF, 0xFB2E]
        display = await client.read_input_registers(600 + 100, count=2, device_id=1)
        assert display.registers == [0xFFFF, 0xFFF9]
        nmt = await client.read_input_registers(600 + 1, count=1, device_id=1)
        assert nmt.registers == [5]
        other_unit = await client.read_input_registers(100, count=2, device_id=125)
        assert other_unit.isError() and other_unit.exception_code == 0x0A
