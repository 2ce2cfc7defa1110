"""Writes that would defeat supervision are refused, with the reason, by every adapter; every
configuration write stays inside the object's range (the device manual via the profile's
constraints, the EDS LowLimit/HighLimit); a write that changes error control, or is refused for
it, is logged naming the write and its client, and the console's event log shows it.

Against our simulator (SGH10: heartbeat supervision, manual 000 4.7.2.14 "0, 10 ... 65535") with
a real Modbus client, a real Zenoh session and a CiA 309-3 ASCII socket, and against python
canopen's LocalNode (an SDO server that is not ours) built from an EDS."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from canopen_gateway.app import Gateway
from canopen_gateway.errors import SupervisionWrite, ValueOutOfRange
from tests.helpers import edited_copy, free_port, gateway_of, make_config, wait_until
from tests.integration.test_eds_devices import gateway_with
from tests.integration.test_web_http import post
from tests.zenoh_client import ZClient

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 100}
SPARE = {"name": "spare", "node_id": 2, "profile": "sgh10", "supervision": "none"}
P = "canopen/test"
TOKEN = "plant-floor-token-42"
ILLEGAL_VALUE = 0x03
# test_eds_devices.gateway_with: python canopen's LocalNode from an EDS as node 5, named io (the
# test sends its boot-up and heartbeat), with neither Modbus nor Zenoh
LOCAL = {"modbus": {"enabled": False}, "zenoh": {"enabled": False}}
IO401 = Path(__file__).resolve().parents[1] / "data" / "eds" / "io401.eds"


@asynccontextmanager
async def gateway() -> AsyncIterator[tuple[Gateway, AsyncModbusTcpClient, ZClient]]:
    cfg = make_config(
        [WIRE, SPARE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        health={"port": free_port()},
        web={"enabled": True, "writes": True, "token": TOKEN},
        zenoh={"writes": True},
        ascii={"port": free_port(), "writes": True},
    )
    gw = gateway_of(cfg)
    await gw.start()
    z = ZClient(cfg.zenoh.listen)
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    try:
        await client.connect()
        for name in ("wire", "spare"):
            await wait_until(lambda n=name: gw.image.nodes[n].usable(), 8, f"{name} usable")
        yield gw, client, z
    finally:
        client.close()
        z.close()
        await gw.stop()


def register_of(gw: Gateway, node: str, signal: str) -> tuple[int, int]:
    """(unit, holding register) of a node's signal, from the gateway's own register map."""
    for p in gw.modbus.regmap.points:
        if p.node == node and p.name == signal and p.table == "hr":
            return p.unit, p.address
    raise AssertionError(f"{node}.{signal} is not in the register map")


def sim_value(gw: Gateway, node: str, index: int, sub: int) -> Any:
    assert gw.sim is not None
    return gw.sim.runner.call(lambda now: gw.sim.nodes[node].get(index, sub))


def code(rr: Any) -> int | None:
    return rr.exception_code if isinstance(rr, ExceptionResponse) else None


async def ascii_request(port: int, line: str) -> str:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(line.encode() + b"\r\n")
        await writer.drain()
        return (await asyncio.wait_for(reader.readline(), 15)).decode().strip()
    finally:
        writer.close()


def warnings_of(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


async def test_heartbeat_time_0_on_a_heartbeat_supervised_node_is_refused_by_every_adapter(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The mbpoll slip of the issue: 1017h = 0 would make the node "lost" at once. Modbus
    answers exception 03, Zenoh reply_err, ASCII the SDO abort 0x08000022; the device keeps its
    heartbeat, the gateway keeps the node, and each refusal is logged naming its client."""
    caplog.set_level(logging.WARNING, logger="gateway")
    async with gateway() as (gw, client, z):
        unit, address = register_of(gw, "wire", "heartbeat_time")
        rr = await client.write_register(address, 0, device_id=unit)
        assert code(rr) == ILLEGAL_VALUE

        by_name = await z.get_one(f"{P}/wire/set/heartbeat_time", payload="0")
        assert not by_name.ok and by_name.body["error"] == "supervision_write", by_name.body
        assert "supervised by its heartbeat" in by_name.body["message"]
        by_sdo = await z.get_one(f"{P}/wire/sdo/1017/00", payload="0")
        assert not by_sdo.ok and by_sdo.body["error"] == "supervision_write", by_sdo.body

        answer = await ascii_request(gw.cfg.ascii.port, "[7] 1 w 0x1017 0 u16 0")
        assert answer == "[7] ERROR:0x08000022"
        # the same 0 in four bytes is the same write
        answer = await ascii_request(gw.cfg.ascii.port, "[9] 1 w 0x1017 0 u32 0")
        assert answer == "[9] ERROR:0x08000022"

        base = f"http://127.0.0.1:{gw.health.port}"
        status, doc = await post(base, "sdo-write", {"node": "wire", "object": "0x1017:00", "value": 0})
        assert status >= 400 and "supervised by its heartbeat" in doc["message"], (status, doc)

        with pytest.raises(SupervisionWrite, match="heartbeat_ms in the config"):
            await gw.commands.sdo_write("wire", "0x1017:00", 0)
        # a write of the value the gateway configured changes nothing and is allowed
        await gw.commands.sdo_write("wire", "0x1017:00", 100)

        assert sim_value(gw, "wire", 0x1017, 0) == 100
        assert gw.image.nodes["wire"].health.alive
        refused = [m for m in warnings_of(caplog) if "refused" in m and "0x1017:00" in m]
        # modbus, the zenoh set and SDO, ascii (address:port), the web console
        for who, n in (("modbus 127.0.0.1:", 1), ("zenoh", 2), ("ascii 127.0.0.1:", 2), ("web 127.0.0.1 token:", 1)):  # fmt: skip
            assert len([m for m in refused if m.startswith(who)]) == n, (who, refused)
        events = [e.text for e in gw.web.events.since(0)]
        assert any(t.startswith("modbus 127.0.0.1:") and "refused" in t for t in events), events


async def test_heartbeat_time_outside_the_manuals_range_is_refused_and_a_change_is_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A node the gateway does not supervise (supervision: none): 1017h = 5 is outside the
    SGH10 manual's "0 or 10..65535" and refused (exception 03, the device unchanged); 20 is
    written, and the log names the write and its client."""
    caplog.set_level(logging.WARNING, logger="gateway")
    async with gateway() as (gw, client, _z):
        unit, address = register_of(gw, "spare", "heartbeat_time")
        before = sim_value(gw, "spare", 0x1017, 0)
        assert code(await client.write_register(address, 5, device_id=unit)) == ILLEGAL_VALUE
        assert sim_value(gw, "spare", 0x1017, 0) == before
        with pytest.raises(ValueOutOfRange, match=r"0 or 10\.\.65535"):
            await gw.commands.sdo_write("spare", "0x1017:00", 5)
        assert await ascii_request(gw.cfg.ascii.port, "[8] 2 w 0x1017 0 u16 5") == "[8] ERROR:101"
        assert sim_value(gw, "spare", 0x1017, 0) == before

        assert code(await client.write_register(address, 20, device_id=unit)) is None
        assert sim_value(gw, "spare", 0x1017, 0) == 20
        changed = [m for m in warnings_of(caplog) if "wrote 0x1017:00 = 20 on node spare" in m]
        assert changed and changed[0].startswith("modbus 127.0.0.1 wrote"), warnings_of(caplog)
        assert changed[0].endswith("(error control; the gateway does not supervise it)")


async def test_localnode_keeps_its_heartbeat_and_limits_from_its_eds_hold(tmp_path: Path) -> None:
    """An EDS-only node on another stack: 1017h other than the configured 300 ms is refused
    before anything is sent; an EDS LowLimit/HighLimit (1800h:05 10..1000 here) bounds every
    configuration write; a value inside is written to the device."""
    eds = edited_copy(
        tmp_path,
        IO401,
        "[1800sub5]\nParameterName=Event timer\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\n",
        "[1800sub5]\nParameterName=Event timer\nObjectType=0x7\nDataType=0x0006\nAccessType=rw\n"
        "LowLimit=10\nHighLimit=1000\n",
    )
    async with gateway_with(eds, 5, "io", {"heartbeat_ms": 300}, sections=LOCAL) as (gw, dev, _b, _l):
        assert int.from_bytes(dev.get_data(0x1017, 0), "little") == 300
        for value in (0, 5, 1000):
            with pytest.raises(SupervisionWrite):
                await gw.commands.sdo_write("io", "0x1017:00", value)
        with pytest.raises(ValueOutOfRange, match=r"10\.\.1000 \(LowLimit/HighLimit"):
            await gw.commands.sdo_write("io", "0x1800:05", 5000)
        await gw.commands.sdo_write("io", "0x1800:05", 500)
        assert int.from_bytes(dev.get_data(0x1800, 5), "little") == 500
        assert int.from_bytes(dev.get_data(0x1017, 0), "little") == 300
        assert gw.image.nodes["io"].health.alive


async def test_a_consumer_of_the_masters_heartbeat_set_at_boot_is_kept(tmp_path: Path) -> None:
    """A POSI+ (python canopen's LocalNode from its EDS) whose config makes it watch the
    master's heartbeat (1016h:01 = master id 127, 1500 ms): a write that would stop that is
    refused and the device keeps the entry; the configured value may be written again."""
    from canopen_gateway.profiles import load_profile

    watching = (127 << 16) | 1500
    node = {"profile": "posi_plus", "sdo": [{"object": "0x1016:01", "value": watching}]}
    eds = load_profile("posi_plus").eds_path
    async with gateway_with(eds, 5, "io", node, sections=LOCAL) as (gw, dev, _b, _l):
        assert int.from_bytes(dev.get_data(0x1016, 1), "little") == watching
        with pytest.raises(SupervisionWrite, match="watching the master's heartbeat"):
            await gw.commands.sdo_write("io", "0x1016:01", 0)
        with pytest.raises(SupervisionWrite):
            await gw.commands.write_bits("io", "consumer_heartbeat_time", {16: False})
        await gw.commands.sdo_write("io", "0x1016:01", watching)
        assert int.from_bytes(dev.get_data(0x1016, 1), "little") == watching


async def test_guard_time_and_a_heartbeat_on_a_guarded_node_are_refused() -> None:
    """Our simulated POSI+ supervised by node guarding (guard 200 ms, factor 3): 100Ch = 0 and
    100Dh = 0 would end guarding, 1017h = 100 would replace it by a heartbeat; each is refused,
    the device keeps its values and the node stays alive."""
    rotary = {"name": "rotary", "node_id": 3, "profile": "posi_plus", "supervision": "guarding",
              "guard_time_ms": 200, "life_time_factor": 3}  # fmt: skip
    gw = gateway_of(make_config([rotary], modbus={"enabled": False}, zenoh={"enabled": False}))
    await gw.start()
    try:
        await wait_until(lambda: gw.image.nodes["rotary"].usable(), 8, "rotary usable")
        for obj, value, why in (
            ("0x100C:00", 0, "100Ch = 200 ms"),
            ("0x100D:00", 0, "100Dh = 3"),
            ("0x1017:00", 100, "takes precedence"),
        ):
            with pytest.raises(SupervisionWrite, match=why):
                await gw.commands.sdo_write("rotary", obj, value)
        assert (sim_value(gw, "rotary", 0x100C, 0), sim_value(gw, "rotary", 0x100D, 0)) == (200, 3)
        assert sim_value(gw, "rotary", 0x1017, 0) == 0
        assert gw.image.nodes["rotary"].health.alive
    finally:
        await gw.stop()
