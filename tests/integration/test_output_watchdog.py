"""The Modbus output watchdog end to end: a CiA 401 I/O module known from its EDS alone, played
by python canopen's LocalNode on a virtual bus (boot-up and heartbeat sent by the test), a real
pymodbus client as the PLC. When the PLC falls silent (or its connection goes), the RPDOs with
the safe values are seen on the bus, outputs without a safe value keep theirs, the node says
``outputs: safe`` in /healthz, Modbus, Zenoh and the console's view, the trip is counted, and
the PLC's next write takes over again. Only clients allowed to write feed it: an HMI that
only may read (outside ``allowed_networks``, a TLS role with ``read``) keeps nothing alive, and
a PLC that connects per transaction is no PLC gone."""

from __future__ import annotations

import asyncio
import json
import logging
import urllib.request
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.checks import check_config
from canopen_gateway.config import ConfigError
from tests.helpers import free_port, gateway_of, make_config, wait_until, with_nodes
from tests.integration.test_eds_devices import IO, SdoLog, gateway_with
from tests.integration.test_modbus_tls import SET_POINT1, Pki, client_for, secure_gateway
from tests.zenoh_client import ZClient, sample_where

UNIT = 5
OUT_1_8, OUT_9_10, OUT_1_10, ANALOGUE_1 = 100, 101, 102, 103  # holding registers (RPDO signals)
OUTPUTS_SAFE = 4  # discrete input of the node's diagnostics
RPDO1, RPDO2 = 0x205, 0x305  # 6200h:01, 6200h:02 | 6300h:01, 6411h:01
SAFE = {"write_output_1h_to_8h": 0, "analogue_output_1": -1}
UNIT_AP05 = 125  # the AP05 display of the TLS tests (tests/integration/test_modbus_tls.py)


@asynccontextmanager
async def io_gateway(modbus: dict[str, Any], **sections: Any) -> AsyncIterator[tuple[Gateway, SdoLog]]:
    """The IO module (python canopen's LocalNode from its EDS) with its safe outputs, and every
    frame on the bus recorded (test_eds_devices.gateway_with)."""
    async with gateway_with(
        IO, UNIT, "io", {"safe_outputs": SAFE}, sections={"modbus": modbus, **sections}
    ) as (gw, _node, _sniffer, frames):
        yield gw, frames


def sent(frames: SdoLog, cob_id: int) -> list[bytes]:
    return [data for cob, data in list(frames.frames) if cob == cob_id]


async def plc_writes(client: AsyncModbusTcpClient) -> None:
    """The PLC sets every output: RPDO1 [FF 03], RPDO2 [34 12 | F4 01]."""
    for address, value in ((OUT_1_8, 0xFF), (OUT_9_10, 0x03), (OUT_1_10, 0x1234), (ANALOGUE_1, 500)):
        rr = await client.write_register(address, value, device_id=UNIT)
        assert not rr.isError(), rr


async def test_silent_plc_gets_safe_outputs_once_and_its_next_write_takes_over() -> None:
    async with io_gateway({"watchdog_ms": 300}) as (gw, frames):
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        z = ZClient(gw.cfg.zenoh.listen)
        states = z.subscribe("canopen/test/io/state")
        try:
            await plc_writes(client)
            await wait_until(lambda: bytes.fromhex("3412f401") in sent(frames, RPDO2), 5, "PLC's RPDO2")
            assert gw.image.nodes["io"].health.outputs == "normal"
            # the PLC falls silent (connected, no request): after 300 ms the safe values go out
            await wait_until(lambda: bytes.fromhex("3412ffff") in sent(frames, RPDO2), 5, "safe RPDO2")
            # 6200h:01 safe 0; 6200h:02 has no safe value: keeps 03; 6300h:01 keeps 1234h
            assert bytes.fromhex("0003") in sent(frames, RPDO1)
            assert gw.image.nodes["io"].health.outputs == "safe"
            assert gw.modbus.watchdog.trips == {"timeout": 1, "disconnect": 0}
            assert gw.status()["nodes"]["io"]["outputs"] == "safe"
            assert gw.status()["modbus_watchdog"]["trips"]["timeout"] == 1
            sample = await sample_where(states, lambda s: s.body.get("outputs") == "safe", 5)
            assert sample.body["node"] == "io"
            # written once: no further RPDO while silent (the trip happened; the machine
            # has no deadline until the next request)
            assert gw.modbus.watchdog.next_deadline() is None
            # Modbus: the node's outputs_safe bit, the gateway's trip counter, the values read back
            bits = await client.read_discrete_inputs(OUTPUTS_SAFE, count=1, device_id=UNIT)
            assert bits.bits[0] is True
            trips = await client.read_input_registers(19, count=2, device_id=247)
            assert trips.registers == [0, 1]
            back = await client.read_holding_registers(OUT_1_8, count=4, device_id=UNIT)
            assert back.registers == [0, 0x03, 0x1234, 0xFFFF]
            # the PLC writes again: that write goes out and the node is back to normal
            rr = await client.write_register(OUT_1_8, 0x0F, device_id=UNIT)
            assert not rr.isError(), rr
            await wait_until(lambda: bytes.fromhex("0f03") in sent(frames, RPDO1), 5, "PLC's RPDO1")
            assert gw.image.nodes["io"].health.outputs == "normal"
            bits = await client.read_discrete_inputs(OUTPUTS_SAFE, count=1, device_id=UNIT)
            assert bits.bits[0] is False
            await sample_where(states, lambda s: s.body.get("outputs") == "normal", 5)
        finally:
            z.close()
            client.close()


async def test_last_client_disconnecting_writes_the_safe_outputs_at_once() -> None:
    health = free_port()
    async with io_gateway(
        {"watchdog_on_disconnect": True}, health={"port": health}
    ) as (gw, frames):
        wd = gw.modbus.watchdog
        # a port check before any PLC talked: connects, sends nothing, goes; nothing is written
        _, probe = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        await wait_until(lambda: wd.writers == 1, 5, "the port check connected")
        probe.close()
        await wait_until(lambda: wd.writers == 0, 5, "the port check gone")
        assert wd.trips == {"timeout": 0, "disconnect": 0} and wd.state == "waiting"
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        await plc_writes(client)
        await wait_until(lambda: bytes.fromhex("3412f401") in sent(frames, RPDO2), 5, "PLC's RPDO2")
        assert gw.modbus.watchdog.next_deadline() is None, "no timeout configured"
        client.close()  # the cable is pulled
        await wait_until(lambda: bytes.fromhex("3412ffff") in sent(frames, RPDO2), 5, "safe RPDO2")
        assert gw.modbus.watchdog.trips == {"timeout": 0, "disconnect": 1}

        def get(path: str) -> str:
            with urllib.request.urlopen(f"http://127.0.0.1:{health}{path}", timeout=5) as r:
                return r.read().decode()

        status = json.loads(await asyncio.to_thread(get, "/healthz"))
        assert status["nodes"]["io"]["outputs"] == "safe"
        assert status["modbus_watchdog"] == {
            "state": "tripped",
            "trips": {"timeout": 0, "disconnect": 1},
        }
        metrics = await asyncio.to_thread(get, "/metrics")
        assert 'canopen_gateway_modbus_watchdog_trips_total{reason="disconnect"} 1.0' in metrics
        row = json.loads(await asyncio.to_thread(get, "/api/node/io"))
        assert row["row"]["outputs"] == "safe"


PLC_ONLY = ["127.0.0.1/32"]  # allowed_networks: the PLC connects from 127.0.0.1
HMI_ADDRESS = ("127.0.0.2", 0)  # an HMI on another loopback address: may read, not write


def hmi_client(gw: Gateway) -> AsyncModbusTcpClient:
    return AsyncModbusTcpClient(
        "127.0.0.1", port=gw.modbus.port, timeout=3, source_address=HMI_ADDRESS
    )


async def hmi_reads(client: AsyncModbusTcpClient) -> None:
    """An HMI's cycle: the outputs (holding registers, served from the image), the node's
    diagnostics bits (served in a task), again and again."""
    while True:
        rr = await client.read_holding_registers(OUT_1_8, count=4, device_id=UNIT)
        assert not rr.isError(), rr
        rr = await client.read_discrete_inputs(0, count=5, device_id=UNIT)
        assert not rr.isError(), rr
        await asyncio.sleep(0.02)  # its cycle time


async def test_an_hmi_that_only_reads_keeps_nothing_alive_when_the_plc_is_gone() -> None:
    async with io_gateway({"watchdog_ms": 300, "allowed_networks": PLC_ONLY}) as (gw, frames):
        wd = gw.modbus.watchdog
        plc = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        hmi = hmi_client(gw)
        await plc.connect()
        await hmi.connect()
        reading = asyncio.create_task(hmi_reads(hmi))
        try:
            await plc_writes(plc)
            await wait_until(lambda: bytes.fromhex("3412f401") in sent(frames, RPDO2), 5, "PLC's RPDO2")
            assert wd.writers == 1, "the HMI is no writer"
            plc.close()  # the PLC dies; the HMI keeps reading
            await wait_until(lambda: bytes.fromhex("3412ffff") in sent(frames, RPDO2), 5, "safe RPDO2")
            assert wd.trips == {"timeout": 1, "disconnect": 0}
            assert not reading.done(), "the HMI read all along"
            await wait_until(lambda: gw.image.nodes["io"].health.outputs == "safe", 5, "outputs safe")
            bits = await hmi.read_discrete_inputs(OUTPUTS_SAFE, count=1, device_id=UNIT)
            assert bits.bits[0] is True
            assert wd.state == "tripped" and wd.next_deadline() is None, "its reads arm nothing"
        finally:
            reading.cancel()
            await asyncio.gather(reading, return_exceptions=True)
            hmi.close()
            plc.close()


async def test_a_plc_gone_with_an_hmi_still_connected_trips_on_disconnect() -> None:
    async with io_gateway(
        {"watchdog_on_disconnect": True, "allowed_networks": PLC_ONLY}
    ) as (gw, frames):
        wd = gw.modbus.watchdog
        hmi = hmi_client(gw)
        await hmi.connect()
        plc = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await plc.connect()
        try:
            await plc_writes(plc)
            rr = await hmi.read_holding_registers(OUT_1_8, count=4, device_id=UNIT)
            assert rr.registers == [0xFF, 0x03, 0x1234, 500]
            plc.close()  # the HMI stays connected: the PLC's connection is the one that counts
            await wait_until(lambda: bytes.fromhex("3412ffff") in sent(frames, RPDO2), 5, "safe RPDO2")
            assert wd.trips == {"timeout": 0, "disconnect": 1}
        finally:
            hmi.close()
            plc.close()


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    ca = Pki(tmp_path_factory.mktemp("pki"))
    return {
        "ca": ca,
        "server": ca.issue("gateway", server=True),
        "operator": ca.issue("plc1", role="Operator"),
        "viewer": ca.issue("hmi1", role="Viewer"),
        "norole": ca.issue("laptop"),
    }


async def test_clients_that_may_not_write_feed_nothing(pki: dict[str, Any]) -> None:
    """An address outside allowed_networks, a TLS role with read access, a TLS client with no
    role: their writes are refused (0x01), and none of their requests arms the watchdog."""
    async with secure_gateway(pki, watchdog_ms=300, allowed_networks=PLC_ONLY) as gw:
        wd = gw.modbus.watchdog
        outsider = hmi_client(gw)
        viewer, norole = client_for(gw, pki, "viewer"), client_for(gw, pki, "norole")
        operator = client_for(gw, pki, "operator")
        clients = (outsider, viewer, norole, operator)
        try:
            for client in clients:
                assert await client.connect()
            await wait_until(lambda: len(gw.modbus.connections) == 4, 5, "four connections")
            assert wd.writers == 1, "the operator only"
            for client in (outsider, viewer, norole):
                rr = await client.write_registers(SET_POINT1, [0, 1], device_id=UNIT_AP05)
                assert rr.isError() and rr.exception_code == 0x01, rr
                await client.read_holding_registers(SET_POINT1, count=2, device_id=UNIT_AP05)
                await client.read_discrete_inputs(0, count=5, device_id=UNIT_AP05)
            assert gw.modbus.store.requests == 9
            assert wd.state == "waiting" and wd.next_deadline() is None, "nothing fed it"
            # the operator (role Operator, from 127.0.0.1) may write: its read arms it
            rr = await operator.read_holding_registers(SET_POINT1, count=2, device_id=UNIT_AP05)
            assert not rr.isError(), rr
            assert wd.state in ("armed", "tripped") and wd.last_request_s is not None
        finally:
            for client in clients:
                client.close()


async def test_a_read_only_gateway_has_no_client_that_feeds_it(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="gateway.modbus"):
        async with io_gateway({"watchdog_ms": 300, "read_only": True}) as (gw, frames):
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
            await client.connect()
            try:
                rr = await client.read_holding_registers(OUT_1_8, count=4, device_id=UNIT)
                assert not rr.isError(), rr
                rr = await client.write_register(OUT_1_8, 1, device_id=UNIT)
                assert rr.isError() and rr.exception_code == 0x01, rr
                wd = gw.modbus.watchdog
                assert wd.state == "waiting" and wd.writers == 0 and wd.next_deadline() is None
            finally:
                client.close()
    assert any("never trips" in r.getMessage() for r in caplog.records), "said at start"


async def plc_transaction(gw: Gateway, value: int) -> None:
    """A PLC that opens a connection for each transaction: connect, write, close."""
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
    await client.connect()
    rr = await client.write_register(OUT_1_8, value, device_id=UNIT)
    assert not rr.isError(), rr
    client.close()
    await wait_until(lambda: gw.modbus.watchdog.writers == 0, 5, "the server saw it close")


async def test_a_plc_that_connects_per_transaction_keeps_its_outputs() -> None:
    # a watchdog time far longer than the test: what trips here trips on a disconnection
    async with io_gateway({"watchdog_ms": 600_000, "watchdog_on_disconnect": True}) as (gw, frames):
        wd = gw.modbus.watchdog
        for value in range(1, 11):
            await plc_transaction(gw, value)
            assert wd.state == "disconnected", "the countdown of the last request runs"
        await wait_until(lambda: bytes.fromhex("0a00") in sent(frames, RPDO1), 5, "the 10th write")
        assert wd.trips == {"timeout": 0, "disconnect": 0}
        assert gw.image.nodes["io"].health.outputs == "normal"
        assert [d[:1] for d in sent(frames, RPDO1)] == [bytes((v,)) for v in range(1, 11)]


async def test_a_plc_that_connects_per_transaction_and_stops_trips_on_disconnect() -> None:
    async with io_gateway({"watchdog_ms": 300, "watchdog_on_disconnect": True}) as (gw, frames):
        await plc_transaction(gw, 0xFF)
        await wait_until(lambda: bytes.fromhex("0000") in sent(frames, RPDO1), 5, "safe RPDO1")
        assert gw.modbus.watchdog.trips == {"timeout": 0, "disconnect": 1}
        assert gw.image.nodes["io"].health.outputs == "safe"


def test_check_names_a_safe_output_that_is_no_rpdo_output() -> None:
    with pytest.raises(ConfigError) as err:
        check_config(
            *with_nodes(make_config(
                [{"name": "io", "node_id": 5, "eds": str(IO), "safe_outputs": {"read_input_1h_to_8h": 0}}]
            ))
        )
    (line,) = [p for p in err.value.problems if "safe_outputs" in p]
    assert "nodes[0].safe_outputs.read_input_1h_to_8h: not an RPDO output of node io" in line
    assert "write_output_1h_to_8h" in line, "names what is allowed"


def test_check_names_a_safe_value_out_of_range() -> None:
    with pytest.raises(ConfigError) as err:
        check_config(
            *with_nodes(make_config(
                [{"name": "io", "node_id": 5, "eds": str(IO), "safe_outputs": {"write_output_1h_to_8h": 300}}]
            ))
        )
    (line,) = [p for p in err.value.problems if "safe_outputs" in p]
    assert "nodes[0].safe_outputs.write_output_1h_to_8h: value 300 not allowed" in line


async def test_simulated_ap05_set_point_falls_back_to_its_safe_value() -> None:
    """Our own simulator on the device side: the AP05's set point 1 (5F16h:03) as the device
    holds it, written by the PLC, then by the watchdog."""
    display = {"name": "display", "node_id": 125, "profile": "ap05", "safe_outputs": {"set_point1": 0}}
    cfg = make_config([display], zenoh={"enabled": False}, modbus={"watchdog_ms": 200})
    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
    try:
        await wait_until(gw.image.nodes["display"].operational, 5, "display operational")
        sim = gw.sim.nodes["display"]

        def set_point1() -> int:
            return gw.sim.runner.call(lambda now: sim.get(0x5F16, 3))

        await client.connect()
        rr = await client.write_registers(100, [0, 4321], device_id=125)
        assert not rr.isError(), rr
        await wait_until(lambda: set_point1() == 4321, 3, "the PLC's set point on the device")
        await wait_until(lambda: set_point1() == 0, 5, "the safe set point on the device")
        assert gw.image.nodes["display"].health.outputs == "safe"
    finally:
        client.close()
        await gw.stop()
