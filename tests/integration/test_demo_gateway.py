"""The walking skeleton end to end: simulated devices -> gateway -> real Modbus TCP client and
real Zenoh subscriber see a changing position."""

from __future__ import annotations

import json
import queue

import zenoh
from pymodbus.client import AsyncModbusTcpClient

from tests.helpers import gateway_of, make_config, wait_until

NODES = [
    {"name": "wire", "node_id": 1, "profile": "sgh10"},
    {"name": "display", "node_id": 125, "profile": "ap05"},
]


def _subscriber(endpoint: str) -> tuple[zenoh.Session, queue.Queue]:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf), queue.Queue()


async def test_position_changes_reach_modbus_and_zenoh() -> None:
    cfg = make_config(
        NODES, simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp", "speed": 2000}}}
    )
    gw = gateway_of(cfg)
    await gw.start()
    session, samples = _subscriber(cfg.zenoh.listen[0])
    sub = session.declare_subscriber(
        "canopen/test/wire/value/position", lambda s: samples.put(json.loads(s.payload.to_bytes()))
    )
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        await client.connect()

        async def read_position() -> int | None:
            rr = await client.read_input_registers(100, count=2, device_id=1)
            if rr.isError():
                return None
            return client.convert_from_registers(rr.registers, client.DATATYPE.INT32)

        # the position is served, then changes (the simulated wire moves)
        first = await read_position()
        assert first is not None, "Modbus did not serve the position of an operational node"
        seq = gw.image.nodes["wire"].signals["position"].seq
        await wait_until(
            lambda: gw.image.nodes["wire"].signals["position"].seq > seq + 5, 5, "new PDOs"
        )
        changed = await read_position()
        assert changed is not None and changed != first, "position did not change over Modbus"

        values = []
        while len(values) < 2:
            s = samples.get(timeout=5)
            assert s["quality"] in ("good", "stale")
            assert s["unit"] == "mm"
            values.append(s["value"])
        assert values[0] != values[1]
    finally:
        client.close()
        sub.undeclare()
        session.close()
        await gw.stop()
