"""AP05 position indicator end to end (AP05 manual 5.3.1.3, 5.3.2, 5.3.3, 5.5.4, 5.5.5):
the manual's frames byte for byte against raw CAN, and the guarding bit, external heartbeat and
alpha-numeric text against the simulated AP05."""

from __future__ import annotations

import asyncio
import json
import queue
import struct
from collections.abc import Callable
from typing import Any

import can
import pytest
import zenoh
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from canopen_gateway.app import Gateway
from canopen_gateway.image import LinkState, NmtState
from tests.helpers import free_port, gateway_of, make_config, operational, simulated_bus, wait_until
from tests.zenoh_client import ZClient

# register map of an AP05 unit (see docs/modbus.md): holding registers
SET_POINT2 = 103  # int32, 103-104
CHARS2 = 105
CONTROL_WORD = 106
POSITION = 100  # input registers 100-101
STATUS_WORD = 102
TEXT1 = 169  # string[6] 169-171
TEXT2 = 172
P = "canopen/test"


def raw_ap05(**node: object) -> dict:
    """An AP05 of frames scripted by the test: no SDO server, so no 1018h to check."""
    return {"name": "display", "node_id": 1, "profile": "ap05", "configure": False, "identity_check": False, **node}


async def _raw_gateway(nodes: list[dict], **sections: object) -> tuple[Gateway, can.BusABC]:
    cfg = make_config(nodes, simulate={"nodes": []}, **sections)
    gw = gateway_of(cfg)
    await gw.start()
    bus = can.Bus(interface="virtual", channel=cfg.can.channel, receive_own_messages=False)
    return gw, bus


def _operational_by_heartbeat(bus: can.BusABC, node_id: int) -> None:
    """Boot-up (the gateway answers with NMT start: values are fresh from then on), then an
    operational heartbeat, as a device sends them."""
    bus.send(can.Message(arbitration_id=0x700 + node_id, data=b"\x00", is_extended_id=False))
    bus.send(can.Message(arbitration_id=0x700 + node_id, data=b"\x05", is_extended_id=False))


def _recv_cob(bus: can.BusABC, cob: int, timeout_s: float = 3.0, prefix: bytes = b"") -> can.Message:
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = bus.recv(timeout=0.05)
        if msg is not None and msg.arbitration_id == cob and bytes(msg.data).startswith(prefix):
            return msg
    raise AssertionError(f"no frame 0x{cob:03X} within {timeout_s} s")


@pytest.mark.parametrize(("guarding", "last_byte"), [(False, 0x02), (True, 0x03)])
async def test_plc_set_point_300_with_set_point2_valid_is_the_manuals_rpdo2(
    guarding: bool, last_byte: int
) -> None:
    """AP05 5.3.1.3: RPDO2 0x301 2C 01 00 00 00 00 00 02; bit 8 is the guarding bit
    (the first toggle sent is 1)."""
    gw, bus = await _raw_gateway([raw_ap05(guarding_bit={"enabled": guarding})])
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    try:
        _operational_by_heartbeat(bus, 1)
        await wait_until(lambda: gw.image.nodes["display"].health.alive, 3, "node alive")
        await client.connect()
        # set point 2 (int32 big-endian words), characters 5-6 (dummy), control word bit 9
        regs = [0, 300, 0, 0x0200]
        rr = await client.write_registers(SET_POINT2, regs, device_id=1)
        assert not rr.isError(), rr
        # (with the guarding bit on, keep-alive RPDOs go out too: pick the PLC's write)
        msg = await asyncio.to_thread(_recv_cob, bus, 0x301, 3.0, b"\x2c\x01")
        assert bytes(msg.data) == bytes([0x2C, 0x01, 0, 0, 0, 0, 0, last_byte])
    finally:
        client.close()
        bus.shutdown()
        await gw.stop()


async def test_manual_tpdos_read_as_position_and_status_word() -> None:
    """TPDO2 0x281 FA 00 00 00 00 00 01 04 = position 250, status 0401h (CW, set point 2 valid);
    TPDO1 0x1FD 64 00 .. = position 100 of node 125."""
    gw, bus = await _raw_gateway(
        [raw_ap05(), raw_ap05(name="second", node_id=125)]
    )
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    try:
        _operational_by_heartbeat(bus, 1)
        _operational_by_heartbeat(bus, 125)
        await wait_until(
            lambda: gw.image.nodes["display"].health.alive and gw.image.nodes["second"].health.alive,
            3,
            "nodes alive",
        )
        bus.send(can.Message(arbitration_id=0x281, data=bytes.fromhex("FA00000000000104"), is_extended_id=False))
        bus.send(can.Message(arbitration_id=0x1FD, data=bytes.fromhex("6400000000000000"), is_extended_id=False))
        await wait_until(lambda: gw.image.nodes["second"].signals["position"].seq, 3, "TPDO1 of 125")
        await wait_until(lambda: gw.image.nodes["display"].signals["position"].seq, 3, "TPDO2 of 1")
        await client.connect()
        rr = await client.read_input_registers(POSITION, count=3, device_id=1)
        assert not rr.isError(), rr
        assert struct.unpack(">iH", struct.pack(">HHH", *rr.registers)) == (250, 0x0401)
        bits = await client.read_discrete_inputs(100, count=16, device_id=1)
        assert bits.bits[0] is True  # direction CW
        assert bits.bits[10] is True  # set point 2 valid
        assert bits.bits[1] is False  # direction CCW
        rr = await client.read_input_registers(POSITION, count=2, device_id=125)
        assert struct.unpack(">i", struct.pack(">HH", *rr.registers))[0] == 100
    finally:
        client.close()
        bus.shutdown()
        await gw.stop()


AP05_SIM = {"name": "display", "node_id": 5, "profile": "ap05"}


def _subscribe_liveliness(endpoint: str, key: str) -> tuple[zenoh.Session, queue.Queue, object]:
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    s = zenoh.open(conf)
    q: queue.Queue = queue.Queue()
    sub = s.liveliness().declare_subscriber(key, lambda smp: q.put(str(smp.kind)), history=True)
    return s, q, sub


async def test_frozen_guarding_echo_faults_the_link_then_recovers() -> None:
    cfg = make_config(
        [{**AP05_SIM, "guarding_bit": {"tolerance_missed": 3, "tolerance_ms": 400, "period_ms": 50}}]
    )
    gw = gateway_of(cfg)
    await gw.start()
    session, kinds, sub = _subscribe_liveliness(cfg.zenoh.listen[0], "canopen/test/alive/display")
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    node = gw.image.nodes["display"]
    rt = gw.master.nodes["display"]
    try:
        await wait_until(lambda: node.health.link == LinkState.OK, 5, "link OK")
        # many cycles: every toggle echoed
        start = rt.gbit.echoes
        await wait_until(lambda: rt.gbit.echoes >= start + 10, 5, "10 more echoes")
        assert node.health.link == LinkState.OK
        assert await asyncio.to_thread(kinds.get, True, 5) == "SampleKind.PUT"
        await client.connect()
        ok = await client.read_input_registers(POSITION, count=2, device_id=5)
        assert not ok.isError()

        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].freeze_guarding_echo(True, now))
        await wait_until(lambda: node.health.link == LinkState.FAULT, 5, "link FAULT")
        assert await asyncio.to_thread(kinds.get, True, 5) == "SampleKind.DELETE"
        rr = await client.read_input_registers(POSITION, count=2, device_id=5)
        assert isinstance(rr, ExceptionResponse) and rr.exception_code == 0x0B
        diag = await client.read_input_registers(10, count=1, device_id=5)
        assert diag.registers == [2]  # link state fault

        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].freeze_guarding_echo(False, now))
        await wait_until(lambda: node.health.link == LinkState.OK, 5, "link OK again")
        assert await asyncio.to_thread(kinds.get, True, 5) == "SampleKind.PUT"
        rr = await client.read_input_registers(POSITION, count=2, device_id=5)
        assert not rr.isError()
    finally:
        client.close()
        sub.undeclare()
        session.close()
        await gw.stop()


@pytest.mark.parametrize("source", ["rpdo", "sync"])
async def test_external_heartbeat_is_fed_and_the_device_stays_operational(source: str) -> None:
    node = {**AP05_SIM, "external_heartbeat": {"interval_ms": 200, "source": source}}
    cfg = make_config([node], master={"sync_period_ms": 50})
    gw = gateway_of(cfg)
    await gw.start()
    sim = gw.sim.nodes["display"]
    try:
        await wait_until(lambda: gw.image.nodes["display"].operational(), 5, "operational")
        assert sim.sdo_read_local("0x5F09:01") == 200
        assert sim.sdo_read_local("0x5F09:02") == (0 if source == "rpdo" else 1)
        # five intervals pass (counted in heartbeats received from the device) and it stays up
        boots = gw.image.nodes["display"].health.boot_count
        hb = gw.master.nodes["display"].hb
        seen = hb.heartbeats if hasattr(hb, "heartbeats") else None
        sent = gw.image.counters["frames_out"]
        await wait_until(lambda: gw.image.counters["frames_out"] >= sent + 20, 5, "20 frames out")
        assert int(sim.nmt_state) == 5
        assert gw.image.nodes["display"].health.boot_count == boots
        assert seen is None or hb.heartbeats > seen
    finally:
        await gw.stop()


async def test_gateway_stopped_device_drops_to_pre_operational() -> None:
    node = {**AP05_SIM, "external_heartbeat": {"interval_ms": 200, "source": "rpdo"}}
    cfg = make_config([node])
    sim = simulated_bus(cfg)
    sim.start()
    gw = gateway_of(cfg, simulate=False)
    await gw.start()
    try:
        await wait_until(lambda: gw.image.nodes["display"].operational(), 5, "operational")
        assert int(sim.nodes["display"].nmt_state) == 5
        await gw.stop()
        await wait_until(lambda: int(sim.nodes["display"].nmt_state) == 127, 3, "pre-operational")
        # a gateway started again sees and reports that state, then starts the node again
        gw2 = gateway_of(cfg, simulate=False)
        await gw2.start()
        try:
            await wait_until(
                lambda: gw2.image.nodes["display"].health.nmt_state
                in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL),
                3,
                "state reported",
            )
            await wait_until(lambda: gw2.image.nodes["display"].operational(), 5, "restarted")
        finally:
            await gw2.stop()
    finally:
        sim.stop()


async def test_alphanumeric_text_round_trip_and_invalid_text_refused(
    modbus_gateway: Callable[..., Any],
) -> None:
    node = {**AP05_SIM, "sdo": [{"object": "0x5F1B:02", "value": 3}]}
    cfg = make_config([node])
    async with modbus_gateway(cfg, [(operational("display"), "operational")]) as (gw, client):
        sim = gw.sim.nodes["display"]
        regs = [ord("H") << 8 | ord("E"), ord("L") << 8 | ord("L"), ord("O") << 8 | ord("!")]
        rr = await client.write_registers(TEXT1, regs, device_id=5)
        assert not rr.isError(), rr
        await wait_until(lambda: sim.sdo_read_local("0x5F16:03") != 0, 3, "set point 1 received")
        head = struct.pack("<i", sim.sdo_read_local("0x5F16:03"))
        tail = sim.sdo_read_local("0x5F16:04")
        tail = tail if isinstance(tail, (bytes, bytearray)) else struct.pack("<H", tail)
        assert head + bytes(tail) == b"HELLO!"
        assert sim.sdo_read_local("0x5F0C:00") & 0x80  # data identifier ASCII
        back = await client.read_holding_registers(TEXT1, count=3, device_id=5)
        assert back.registers == regs
        # non-ASCII and too long are refused with 0x03 and change nothing
        bad = await client.write_registers(TEXT2, [0xC3A9, 0x4142, 0x4344], device_id=5)
        assert isinstance(bad, ExceptionResponse) and bad.exception_code == 0x03
        with pytest.raises(Exception) as exc:
            await gw.commands.write_signal("display", "set_point2_text", "TOOLONG")
        assert "at most 6" in str(exc.value)


async def test_text_through_zenoh_and_invalid_text_gets_reply_err() -> None:
    node = {**AP05_SIM, "sdo": [{"object": "0x5F1B:02", "value": 3}]}
    cfg = make_config([node], zenoh={"writes": True})
    gw = gateway_of(cfg)
    await gw.start()
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps(cfg.zenoh.listen))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        await wait_until(lambda: gw.image.nodes["display"].operational(), 5, "operational")

        def get(key: str, payload: str) -> list:
            return [r for r in session.get(key, payload=payload, timeout=3)]

        ok = await asyncio.to_thread(get, "canopen/test/display/set/set_point2_text", '"AB 12"')
        assert ok and ok[0].ok is not None
        await wait_until(lambda: gw.sim.nodes["display"].sdo_read_local("0x5F16:01") != 0, 3, "row 2")
        bad = await asyncio.to_thread(get, "canopen/test/display/set/set_point2_text", '"h\u00e9llo"')
        assert bad and bad[0].err is not None
        body = json.loads(bad[0].err.payload.to_bytes())
        assert body["error"] == "value_out_of_range" and "ASCII" in body["message"]
    finally:
        session.close()
        await gw.stop()


async def test_text_written_is_read_back_by_modbus_and_zenoh_from_the_image_outputs(
    modbus_gateway: Callable[..., Any],
) -> None:
    """The outputs are the image's own section, written by the node in one assignment: a text
    row (AP05 manual 4.1.2, sent in one RPDO with the data identifier bit) reads back through
    Modbus and Zenoh (value and snapshot) as written, and no output is echoed into the records
    of received values."""
    node = {**AP05_SIM, "sdo": [{"object": "0x5F1B:02", "value": 3}]}
    cfg = make_config([node], zenoh={"writes": True})
    async with modbus_gateway(cfg, [(operational("display"), "operational")]) as (gw, client):
        image = gw.image.nodes["display"]
        sim = gw.sim.nodes["display"]
        z = ZClient(cfg.zenoh.listen)
        try:
            writes = image.outputs.seq
            regs = [ord("H") << 8 | ord("E"), ord("L") << 8 | ord("L"), ord("O") << 8 | ord("!")]
            rr = await client.write_registers(TEXT1, regs, device_id=5)
            assert not rr.isError(), rr
            assert image.outputs.seq == writes + 1  # one write, one record
            ok = await z.get_one(f"{P}/display/set/set_point2_text", payload='"AB 12"')
            assert ok.ok, ok.body
            await wait_until(lambda: sim.sdo_read_local("0x5F16:01") != 0, 3, "row 2 received")

            back = await client.read_holding_registers(TEXT1, count=3, device_id=5)
            assert back.registers == regs
            row2 = await client.read_holding_registers(TEXT2, count=3, device_id=5)
            assert b"".join(r.to_bytes(2, "big") for r in row2.registers).rstrip(b" \0") == b"AB 12"
            v1 = await z.get_one(f"{P}/display/value/set_point1_text")
            assert v1.ok and v1.body["value"] == "HELLO!", v1.body
            assert v1.body["seq"] == image.outputs.seq
            snap = await z.get_one(f"{P}/display/snapshot")
            assert snap.ok
            assert snap.body["values"]["set_point1_text"]["value"] == "HELLO!"
            assert snap.body["values"]["set_point2_text"]["value"] == "AB 12"
            # outputs live in their own section only: the records hold what the device sent
            outputs = set(gw.commands.node("display").outputs)
            assert not [k for k in image.records if outputs & set(k)]
        finally:
            z.close()


async def test_power_cycle_through_the_runner_reconfigures_the_node() -> None:
    cfg = make_config([AP05_SIM])
    gw = gateway_of(cfg)
    await gw.start()
    node = gw.image.nodes["display"]
    try:
        await wait_until(node.operational, 5, "operational")
        boots = node.health.boot_count
        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].power_cycle(now))
        await wait_until(lambda: node.health.boot_count > boots, 3, "boot-up seen")
        await wait_until(node.operational, 5, "operational again")
    finally:
        await gw.stop()


async def test_static_target_window_is_acknowledged_by_coil_from_the_plc() -> None:
    cfg = make_config([{**AP05_SIM, "guarding_bit": {"enabled": False}}])
    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    sim = gw.sim.nodes["display"]
    try:
        await wait_until(lambda: gw.image.nodes["display"].operational(), 5, "operational")
        await client.connect()
        rr = await client.write_coil(100 + 4, True, device_id=5)  # control bit 4 (table 27)
        assert not rr.isError(), rr
        await wait_until(lambda: sim.sdo_read_local("0x5F0C:00") & 0x10, 3, "ack bit received")
    finally:
        client.close()
        await gw.stop()


async def test_an_output_written_reaches_the_live_web_page_as_its_value() -> None:
    """Outputs are not echoed into the received values; writing them tells the image's value
    listeners all the same, so a browser watching the node sees the set point it was sent."""
    cfg = make_config([AP05_SIM], health={"port": free_port()}, zenoh={"enabled": False})
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(gw.image.nodes["display"].operational, 5, "operational")
        assert gw.web is not None
        page = gw.web.hub.subscribe("display")
        page.dirty_values.clear()
        page.wake.clear()
        await gw.commands.write_signal("display", "set_point2", 4321)
        await asyncio.wait_for(page.wake.wait(), 5)
        assert "set_point2" in page.dirty_values
        row = gw.web.model.values("display", {"set_point2"})["set_point2"]
        assert row == {"value": 4321, "quality": "output"}
        gw.web.hub.unsubscribe(page)
    finally:
        await gw.stop()
