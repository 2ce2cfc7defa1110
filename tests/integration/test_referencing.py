"""MSK5000 (manual 001, 5115h): no valid position before referencing. The gateway never
serves the unreferenced position as good: Modbus 0x0B, quality bad; after referencing, good."""

from __future__ import annotations

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from canopen_gateway.image import Quality
from tests.helpers import gateway_of, make_config, wait_until


async def test_unreferenced_position_is_bad_until_referenced() -> None:
    cfg = make_config([{"name": "magnet", "node_id": 2, "profile": "msk5000"}])
    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    node = gw.image.nodes["magnet"]
    try:
        await wait_until(lambda: node.operational() and node.signals["position"].seq > 0, 5, "position received")
        await wait_until(lambda: not node.is_valid("position"), 3, "position marked not valid")
        assert node.quality(node.signals["position"]) == Quality.BAD
        await client.connect()
        rr = await client.read_input_registers(100, count=2, device_id=2)
        assert isinstance(rr, ExceptionResponse) and rr.exception_code == 0x0B

        await gw.commands.sdo_write("magnet", "0x5115:00", 1)
        await wait_until(lambda: node.is_valid("position"), 3, "position valid after referencing")
        assert node.quality(node.signals["position"]) == Quality.GOOD
        rr = await client.read_input_registers(100, count=2, device_id=2)
        assert not rr.isError()
    finally:
        client.close()
        await gw.stop()
