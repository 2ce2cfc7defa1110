"""A Modbus write refused by the write gate (a client outside ``modbus.allowed_networks``) is
answered 0x01, logged, and audited with the client's address: rate-limited per client and
reason, so a client hammering the gate cannot push older entries out of the journal."""

from __future__ import annotations

from typing import Any

from pymodbus.client import AsyncModbusTcpClient

from tests.helpers import gateway_of, make_config

DISPLAY = [{"name": "display", "node_id": 125, "profile": "ap05"}]


async def test_a_refused_modbus_write_is_audited_once_per_period_with_the_client() -> None:
    cfg = make_config(DISPLAY, zenoh={"enabled": False}, modbus={"allowed_networks": ["127.0.0.1/32"]})
    gw = gateway_of(cfg)
    await gw.start()
    audit: list[dict[str, Any]] = []
    gw.commands.audit = audit.append
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3, source_address=("127.0.0.2", 0))
    try:
        assert await client.connect()
        for value in (1, 2, 3):
            rr = await client.write_registers(100, [0, value], device_id=125)
            assert rr.isError() and rr.exception_code == 0x01
        (record,) = audit
        assert record["who"] == "modbus 127.0.0.2" and record["op"] == "modbus_write"
        assert record["node"] == "unit 125" and record["what"] == "holding register 100"
        assert record["outcome"] == "refused: client 127.0.0.2 is not in modbus.allowed_networks"
    finally:
        client.close()
        await gw.stop()
