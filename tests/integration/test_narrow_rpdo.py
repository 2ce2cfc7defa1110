"""An RPDO entry narrower than its object, against an independent device stack (python
canopen's LocalNode from the same EDS): writes over Modbus and Zenoh are range-checked at the
mapped width, a refused write answers the protocol's own error and changes nothing (not the
frame, not the output image, not the next write)."""

from __future__ import annotations

from pathlib import Path

from pymodbus.client import AsyncModbusTcpClient

from tests.helpers import wait_until
from tests.integration.test_eds_devices import IO, gateway_with
from tests.zenoh_client import ZClient

P = "canopen/test"


def narrow_io(tmp_path: Path) -> Path:
    """io401.eds with RPDO2 entry 2 (6411h:01 INTEGER16, analogue output 1) mapped in 12 bits."""
    text = IO.read_text(encoding="utf-8")
    assert "DefaultValue=0x64110110" in text
    p = tmp_path / "io401_narrow.eds"
    p.write_text(text.replace("DefaultValue=0x64110110", "DefaultValue=0x6411010C", 1), encoding="utf-8")
    return p


def rpdo2(log: list[tuple[int, bytes]]) -> list[bytes]:
    return [data for cob, data in log if cob == 0x305]


async def test_a_narrow_rpdo_entry_is_range_checked_at_its_width_over_modbus_and_zenoh(tmp_path: Path) -> None:
    eds = narrow_io(tmp_path)
    async with gateway_with(eds, 5, "io", sections={"zenoh": {"writes": True}}) as (gw, _node, _bus, log):
        rt = gw.master.nodes["io"]
        await wait_until(lambda: gw.image.nodes["io"].is_valid("read_input_1h_to_8h"), 5, "mapping verified")
        assert rt.mapping_mismatches == []
        assert any("RPDO2 entry 0x6411:01/12" in w and "writes are limited to that width" in w for w in rt.lp.warnings)  # fmt: skip
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            # RPDO2: 6300h:01 UNSIGNED16 (HR 102), 6411h:01 in 12 bits (HR 103): 28 bits, 4 bytes
            assert not (await client.write_register(103, 0xFF9C, device_id=5)).isError()  # -100
            await wait_until(lambda: rpdo2(log.frames) == [bytes.fromhex("00009C0F")], 5, "RPDO2 with -100")
            refused = await client.write_register(103, 3000, device_id=5)  # fits INTEGER16, not 12 bits
            assert refused.isError() and refused.exception_code == 0x03
            held = await client.read_holding_registers(103, count=1, device_id=5)
            assert held.registers == [0xFF9C]  # the output image kept the value sent
            assert not (await client.write_register(102, 5, device_id=5)).isError()
            await wait_until(lambda: len(rpdo2(log.frames)) == 2, 5, "the next RPDO2")
            # before: 3000 went out as 0xBB8 in 12 bits (-1096), and stayed in the image
            assert rpdo2(log.frames) == [bytes.fromhex("00009C0F"), bytes.fromhex("05009C0F")]
        finally:
            client.close()
        z = ZClient(gw.cfg.zenoh.listen)
        try:
            r = await z.get_one(f"{P}/io/set/analogue_output_1", payload="2048")
            assert not r.ok and r.body["error"] == "value_out_of_range", r.body
            assert "-2048..2047 (int16 mapped in 12 bits)" in r.body["message"]
            r = await z.get_one(f"{P}/io/set/analogue_output_1", payload="-2048")
            assert r.ok
        finally:
            z.close()
        await wait_until(lambda: len(rpdo2(log.frames)) == 3, 5, "RPDO2 with -2048")
        assert rpdo2(log.frames)[-1] == bytes.fromhex("05000008")
