"""Simulated devices known only from their file, through a running gateway (our Modbus server
over TCP, the simulator and the master on one virtual bus): a Lely-style DCF whose PDO mappings
are CompactSubObj ``[1A00Value]`` sections serves good values, and its change-driven TPDO (type
255, no event timer) follows the device's value. Device: tests/data/eds/compact.dcf."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from canopen_gateway.image import Quality
from tests.helpers import make_config, modbus_gateway, operational, wait_until

DCF = Path(__file__).resolve().parents[1] / "data" / "eds" / "compact.dcf"
NODE = 10


async def _input_registers(client: Any, address: int, count: int) -> list[int] | None:
    rr = await client.read_input_registers(address, count=count, device_id=NODE)
    return None if rr.isError() else list(rr.registers)


async def test_a_simulated_dcf_with_compact_mappings_serves_good_values_and_follows_changes() -> None:
    cfg = make_config([{"name": "io", "node_id": NODE, "eds": str(DCF)}])
    async with modbus_gateway(cfg, [(operational("io"), "io operational")]) as (gw, client):
        io = gw.image.nodes["io"]
        names = ("analog_input_1", "analog_input_2", "counter")
        await wait_until(
            lambda: all(io.quality(io.signals[n]) == Quality.GOOD for n in names), 5, "values good"
        )
        assert await _input_registers(client, 0, 1) == [0]  # worst quality of the node: good
        assert await _input_registers(client, 100, 4) is not None  # no exception 0x0B

        sim = gw.sim.nodes["io"]
        for position in (4526, 7040, 9511):
            gw.sim.runner.call(lambda _now, p=position: sim.motion.freeze(p))
            counter = position + 14  # 2100h is the node's third automatic input: model + 2 x 7
            await wait_until(lambda c=counter: io.signals["counter"].value == c, 5, f"counter {counter}")
            assert io.quality(io.signals["counter"]) == Quality.GOOD
            assert await _input_registers(client, 102, 2) == [counter >> 16, counter & 0xFFFF]
