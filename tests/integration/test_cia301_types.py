"""The CiA 301 types beyond 32 bits against an independent device stack: a device described by
``tests/data/eds/types.eds`` (REAL64, INTEGER48, TIME_OF_DAY in TPDOs; TIME_DIFFERENCE and
UNSIGNED40 by SDO; 2010h in an RPDO and echoed in a TPDO) is python canopen's LocalNode on a
virtual bus answering SDO; the test sends its TPDOs, built by ``struct`` from the CiA 301
layouts (7.1.4, 7.1.6.5). Values over Modbus TCP (pymodbus client, our server) and Zenoh."""

from __future__ import annotations

import struct
from pathlib import Path

import can
from pymodbus.client import AsyncModbusTcpClient

from tests.helpers import wait_until
from tests.integration.test_eds_devices import gateway_with
from tests.zenoh_client import ZClient

DATA = Path(__file__).resolve().parents[1] / "data" / "eds"
TYPES = DATA / "types.eds"
OVERLAY = DATA / "types.yaml"  # 2004h, 2005h as SDO signals
P = "canopen/test"

ENERGY = 6.02214076e23  # REAL64 2000h
POSITION = -123_456_789_012  # INTEGER48 2001h
#: TIME_OF_DAY 2003h, CiA 301 7.1.6.5: 2026-11-27 08:30:00.250 UTC = 15671 days after
#: 1984-01-01 and 30 600 250 ms after midnight
TOD_DAYS, TOD_MS = 15671, 30_600_250
TOD_UNIX_MS = 1_795_768_200_250
#: TIME_DIFFERENCE 2004h (CiA 301 7.1.6.6): 3 days and 12 345 ms
TD_DAYS, TD_MS = 3, 12_345


def regs_to(fmt: str, regs: list[int]) -> tuple[object, ...]:
    return struct.unpack(fmt, struct.pack(f">{len(regs)}H", *regs))


async def test_real64_integer48_and_time_of_day_from_tpdos_and_a_time_difference_by_sdo() -> None:
    node_extra = {"profile": str(OVERLAY)}
    async with gateway_with(TYPES, 5, "dev", node_extra) as (gw, node, bus, log):
        node.set_data(0x2004, 0, (TD_DAYS << 32 | TD_MS).to_bytes(6, "little"))  # its SDO answer
        tod = TOD_MS.to_bytes(4, "little") + TOD_DAYS.to_bytes(2, "little")
        bus.send(can.Message(arbitration_id=0x185, data=struct.pack("<d", ENERGY), is_extended_id=False))  # fmt: skip
        bus.send(can.Message(arbitration_id=0x285, data=POSITION.to_bytes(6, "little", signed=True) + struct.pack("<H", 0xBEEF), is_extended_id=False))  # fmt: skip
        bus.send(can.Message(arbitration_id=0x385, data=tod + bytes([7]), is_extended_id=False))
        img = gw.image.nodes["dev"]
        names = ("energy", "position", "status", "time_stamp", "command_number")
        await wait_until(lambda: all(img.signals[n].seq and img.is_valid(n) for n in names), 5, "TPDOs decoded, mapping verified")  # fmt: skip
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            regs = (await client.read_input_registers(100, count=14, device_id=5)).registers
            assert regs_to(">d", regs[0:4]) == (ENERGY,)
            assert regs_to(">q", regs[4:8]) == (POSITION,)
            assert regs[8] == 0xBEEF
            assert regs_to(">Q", regs[9:13]) == (TOD_UNIX_MS,)
            assert regs[13] == 7  # 2010h as the device reports it (TPDO3)
            # 2010h is an output too: holding register 108 goes out in RPDO1
            await client.write_register(108, 9, device_id=5)
            await wait_until(lambda: (0x205, bytes([9, 0, 0, 0, 0])) in log.frames, 5, "RPDO1 on the bus")  # fmt: skip
            assert (await client.read_holding_registers(108, count=1, device_id=5)).registers == [9]
            assert (await client.read_input_registers(113, count=1, device_id=5)).registers == [7]
            # TIME_DIFFERENCE by SDO (segmented upload from the LocalNode): milliseconds
            held = (await client.read_holding_registers(100, count=4, device_id=5)).registers
            assert regs_to(">Q", held) == (TD_DAYS * 86_400_000 + TD_MS,)
        finally:
            client.close()
        z = ZClient(gw.cfg.zenoh.listen)
        try:
            r = await z.get_one(f"{P}/dev/value/energy")
            assert r.body["value"] == ENERGY and r.body["quality"] == "good"
            r = await z.get_one(f"{P}/dev/value/position")
            assert r.body["value"] == POSITION
            r = await z.get_one(f"{P}/dev/value/time_stamp")
            assert r.body["value"] == "2026-11-27T08:30:00.250Z"
            r = await z.get_one(f"{P}/dev/value/command_number")
            assert r.body["value"] == 7  # the device's value, not the output
            r = await z.get_one(f"{P}/dev/value/operating_time")
            assert r.body["value"] == TD_DAYS * 86_400_000 + TD_MS and r.body["source"] == "sdo"
        finally:
            z.close()
