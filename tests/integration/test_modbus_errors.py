"""Every Modbus exception path against the gateway with simulated devices, with a real pymodbus
client: unmapped, out of range, read-only, partial writes, SDO aborts (code in IR 12-13), nodes
lost / never booted / not operational, a node that goes silent and comes back, CAN bus down,
unknown unit ids, serve_stale, and write protection."""

from __future__ import annotations

import logging
from contextlib import AbstractAsyncContextManager
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from canopen_gateway.app import Gateway
from canopen_gateway.image import NmtState, Quality
from tests.helpers import make_config, modbus_gateway, wait_until, with_position

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}
HOLD = {"kind": "hold", "min": -5000, "max": 5000, "hold": -1234}

ILLEGAL_FUNCTION, ILLEGAL_ADDRESS, ILLEGAL_VALUE, DEVICE_FAILURE = 0x01, 0x02, 0x03, 0x04
PATH_UNAVAILABLE, NO_RESPONSE = 0x0A, 0x0B

# SGH10 unit 1 holding registers / AP05 unit 125 holding registers (docs/modbus.md)
WIRE_ERROR_COUNT, WIRE_LAST_ERROR, WIRE_CALIBRATION = 111, 112, 116
SET_POINT1, CHARS1, CONTROL_WORD, AP05_ERROR_REGISTER, OPERATING_MODE = 100, 102, 106, 107, 120


def running(
    nodes: list[dict[str, Any]], simulated: list[str] | None = None, **sections: Any
) -> AbstractAsyncContextManager[tuple[Gateway, AsyncModbusTcpClient]]:
    names = [n["name"] for n in nodes] if simulated is None else simulated
    simulate = {"nodes": names, "motion": {n: HOLD for n in names}}
    cfg = make_config(nodes, zenoh={"enabled": False}, simulate=simulate, **sections)
    return modbus_gateway(cfg, [(with_position(name), f"{name} operational") for name in names])


def code(rr: Any) -> int | None:
    """The exception code of a response, None for a normal response."""
    return rr.exception_code if isinstance(rr, ExceptionResponse) else None


def call(gw: Gateway, fn: Any) -> Any:
    return gw.sim.runner.call(fn)


async def test_unmapped_addresses_answer_illegal_data_address() -> None:
    async with running([WIRE]) as (_, client):
        assert code(await client.read_input_registers(50, count=1, device_id=1)) == ILLEGAL_ADDRESS
        # diagnostics 0-15 and process data 100.. with a gap between: one request fails whole
        assert code(await client.read_input_registers(0, count=101, device_id=1)) == ILLEGAL_ADDRESS
        assert code(await client.read_discrete_inputs(5, count=1, device_id=1)) == ILLEGAL_ADDRESS
        assert code(await client.write_register(99, 1, device_id=1)) == ILLEGAL_ADDRESS
        assert code(await client.write_coil(0, True, device_id=1)) == ILLEGAL_ADDRESS
        assert code(await client.read_input_registers(0, count=1, device_id=1)) is None


async def test_writes_to_read_only_points_answer_illegal_data_address() -> None:
    async with running([DISPLAY]) as (gw, client):
        before = call(gw, lambda now: gw.sim.nodes["display"].get(0x1001, 0))
        rr = await client.write_register(AP05_ERROR_REGISTER, 1, device_id=125)
        assert code(rr) == ILLEGAL_ADDRESS
        assert call(gw, lambda now: gw.sim.nodes["display"].get(0x1001, 0)) == before
        rr = await client.write_coil(100, True, device_id=247)
        assert code(rr) == ILLEGAL_ADDRESS, "the gateway unit has no coils"


async def test_a_write_of_part_of_a_32_bit_value_is_refused_and_nothing_is_sent() -> None:
    async with running([DISPLAY]) as (gw, client):
        sent: list[bytes] = []
        gw.image.pdo_listeners.append(
            lambda node, cob, data: sent.append(data) if cob >> 8 in (2, 3) else None
        )  # RPDOs sent (2xxh, 3xxh)
        assert code(await client.write_register(SET_POINT1, 7, device_id=125)) == ILLEGAL_ADDRESS
        rr = await client.write_registers(SET_POINT1 + 1, [7, 0], device_id=125)
        assert code(rr) == ILLEGAL_ADDRESS
        assert all(frame[:4] == bytes(4) for frame in sent), "no set point went out"
        back = await client.read_holding_registers(SET_POINT1, count=2, device_id=125)
        assert back.registers == [0, 0]
        assert call(gw, lambda now: gw.sim.nodes["display"].get(0x5F16, 3)) == 0


async def test_values_out_of_range_or_of_the_wrong_type_answer_illegal_data_value() -> None:
    async with running([WIRE, DISPLAY]) as (gw, client):
        rr = await client.write_register(OPERATING_MODE, 9, device_id=125)  # 0..3
        assert code(rr) == ILLEGAL_VALUE
        assert call(gw, lambda now: gw.sim.nodes["display"].get(0x5F1B, 2)) == 0
        rr = await client.write_registers(WIRE_CALIBRATION, [0, 20000], device_id=1)  # +-10239
        assert code(rr) == ILLEGAL_VALUE
        rr = await client.write_register(CHARS1, 0xC3A9, device_id=125)  # not ASCII
        assert code(rr) == ILLEGAL_VALUE
        assert code(await client.write_register(0, 7, device_id=1)) == ILLEGAL_VALUE, "NMT 7"


async def test_sdo_abort_answers_device_failure_and_the_abort_code_is_in_ir_12_13() -> None:
    async with running([WIRE]) as (_, client):
        # SGH10 manual 4.7.2.4: 1003h:00 accepts only 0 -> abort 0609 0030 (value range)
        rr = await client.write_register(WIRE_ERROR_COUNT, 5, device_id=1)
        assert code(rr) == DEVICE_FAILURE
        diag = await client.read_input_registers(12, count=2, device_id=1)
        assert diag.registers == [0x0609, 0x0030]
        # empty error history: reading 1003h:01 aborts 0800 0024 (no data available)
        rr = await client.read_holding_registers(WIRE_LAST_ERROR, count=2, device_id=1)
        assert code(rr) == DEVICE_FAILURE
        diag = await client.read_input_registers(12, count=2, device_id=1)
        assert diag.registers == [0x0800, 0x0024]
        rr = await client.write_register(WIRE_ERROR_COUNT, 0, device_id=1)
        assert code(rr) is None, "0 clears the history"


async def test_a_node_that_goes_silent_answers_no_response_and_serves_again_when_back() -> None:
    async with running([WIRE, DISPLAY]) as (gw, client):
        wire = gw.sim.nodes["wire"]
        node = gw.image.nodes["wire"]
        call(gw, lambda now: wire.silence())
        await wait_until(lambda: not node.health.alive, 3, "wire lost")
        assert code(await client.read_input_registers(100, count=2, device_id=1)) == NO_RESPONSE
        rr = await client.read_holding_registers(WIRE_ERROR_COUNT, count=1, device_id=1)
        assert code(rr) == NO_RESPONSE, "no SDO to a lost node"
        rr = await client.write_register(WIRE_ERROR_COUNT, 0, device_id=1)
        assert code(rr) == NO_RESPONSE
        diag = (await client.read_input_registers(0, count=10, device_id=1)).registers
        assert diag[0] == 1, "quality stale: last value known"
        assert diag[2] == 0, "not alive"
        assert diag[9] >= 1, "loss counted"
        ok = await client.read_input_registers(100, count=2, device_id=125)
        assert code(ok) is None, "other nodes keep serving"

        call(gw, lambda now: wire.unsilence(now))
        await wait_until(node.operational, 3, "wire back")
        # a loss invalidates every value: good again with the first TPDO after NMT start
        await wait_until(
            lambda: node.quality(node.signals["position"]) == Quality.GOOD, 3, "a fresh TPDO"
        )
        rr = await client.read_input_registers(100, count=2, device_id=1)
        assert code(rr) is None and rr.registers == [0xFFFF, 0xFB2E]
        assert (await client.read_input_registers(0, count=1, device_id=1)).registers == [0]


async def test_a_node_that_never_booted_answers_no_response() -> None:
    ghost = {"name": "ghost", "node_id": 9, "profile": "sgh10"}
    async with running([WIRE, ghost], simulated=["wire"]) as (_, client):
        assert code(await client.read_input_registers(100, count=2, device_id=9)) == NO_RESPONSE
        rr = await client.read_holding_registers(WIRE_ERROR_COUNT, count=1, device_id=9)
        assert code(rr) == NO_RESPONSE
        diag = (await client.read_input_registers(0, count=4, device_id=9)).registers
        assert diag == [2, 0xFFFF, 0, 0], "bad, NMT unknown, not alive, waiting"


async def test_a_stopped_node_answers_no_response_until_started_again() -> None:
    async with running([WIRE], master={"sdo_timeout_s": 0.2, "sdo_retries": 0}) as (gw, client):
        node = gw.image.nodes["wire"]
        assert code(await client.write_register(0, 2, device_id=1)) is None  # NMT stop
        await wait_until(lambda: node.health.nmt_state == NmtState.STOPPED, 3, "stopped")
        assert code(await client.read_input_registers(100, count=2, device_id=1)) == NO_RESPONSE
        rr = await client.write_register(WIRE_ERROR_COUNT, 0, device_id=1)
        assert code(rr) == NO_RESPONSE, "a stopped node does not answer SDO"
        assert (await client.read_holding_registers(0, count=1, device_id=1)).registers == [4]
        assert code(await client.write_register(0, 1, device_id=1)) is None  # NMT start
        await wait_until(node.operational, 3, "operational again")
        # good again only with a TPDO received after the new start
        await wait_until(lambda: node.quality(node.signals["position"]) == Quality.GOOD, 3, "a fresh position")
        assert code(await client.read_input_registers(100, count=2, device_id=1)) is None


async def test_a_write_not_confirmed_within_write_timeout_answers_no_response() -> None:
    sections = {
        "master": {"sdo_timeout_s": 30.0, "sdo_retries": 0},
        "modbus": {"write_timeout_s": 0.2},
    }
    async with running([WIRE], **sections) as (gw, client):
        node = gw.image.nodes["wire"]
        assert code(await client.write_register(0, 2, device_id=1)) is None
        await wait_until(lambda: node.health.nmt_state == NmtState.STOPPED, 3, "stopped")
        rr = await client.write_register(WIRE_ERROR_COUNT, 0, device_id=1)
        assert code(rr) == NO_RESPONSE
        # answered at write_timeout_s: the SDO download (30 s timeout) is still waiting
        assert gw.master.nodes["wire"].node.sdo_busy()


async def test_can_bus_down_answers_gateway_path_unavailable_then_recovers() -> None:
    async with running([WIRE], can={"reopen_backoff_s": 1.0}) as (gw, client):
        bus = gw.driver.bus
        assert bus is not None
        bus.shutdown()  # the backend fails under the reader thread: the driver marks it down
        await wait_until(lambda: gw.image.bus_state == "down", 2, "bus down")
        assert (
            code(await client.read_input_registers(100, count=2, device_id=1)) == PATH_UNAVAILABLE
        )
        rr = await client.write_register(WIRE_ERROR_COUNT, 0, device_id=1)
        assert code(rr) == PATH_UNAVAILABLE
        assert code(await client.write_register(0, 1, device_id=1)) == PATH_UNAVAILABLE, "NMT"
        state = await client.read_input_registers(0, count=1, device_id=247)
        assert state.registers == [0], "the gateway unit reports the bus down"
        assert code(await client.read_input_registers(0, count=4, device_id=1)) is None
        await wait_until(lambda: gw.image.bus_state == "ok", 5, "bus reopened")
        node = gw.image.nodes["wire"]
        await wait_until(node.operational, 5, "wire operational after the reopen")
        # the loss invalidated the values: good again with a TPDO after the new NMT start
        await wait_until(
            lambda: node.quality(node.signals["position"]) == Quality.GOOD, 3, "a fresh TPDO"
        )
        assert code(await client.read_input_registers(100, count=2, device_id=1)) is None


async def test_a_unit_id_without_a_node_answers_gateway_path_unavailable() -> None:
    async with running([WIRE]) as (_, client):
        assert code(await client.read_input_registers(0, count=1, device_id=99)) == PATH_UNAVAILABLE
        assert code(await client.write_register(0, 1, device_id=0)) == PATH_UNAVAILABLE


async def test_serve_stale_serves_the_last_value_with_the_stale_flag_instead_of_no_response() -> (
    None
):
    stale = {**WIRE, "modbus": {"serve_stale": True}}
    strict = {"name": "wire2", "node_id": 2, "profile": "sgh10"}
    async with running([stale, strict]) as (gw, client):
        for name in ("wire", "wire2"):
            sim = gw.sim.nodes[name]
            call(gw, lambda now, sim=sim: sim.silence())
        for name in ("wire", "wire2"):
            await wait_until(lambda n=name: not gw.image.nodes[n].health.alive, 3, f"{name} lost")
        rr = await client.read_input_registers(100, count=2, device_id=1)
        assert code(rr) is None and rr.registers == [0xFFFF, 0xFB2E], "last value served"
        assert (await client.read_input_registers(0, count=1, device_id=1)).registers == [1]
        assert code(await client.read_input_registers(100, count=2, device_id=2)) == NO_RESPONSE
        assert (await client.read_input_registers(0, count=1, device_id=2)).registers == [1]


async def test_read_only_gateway_refuses_every_write_with_illegal_function_and_logs_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with running([DISPLAY], modbus={"read_only": True}) as (gw, client):
        caplog.set_level(logging.WARNING, logger="gateway.modbus")
        sim = gw.sim.nodes["display"]
        assert code(await client.write_register(CONTROL_WORD, 4, device_id=125)) == ILLEGAL_FUNCTION
        rr = await client.write_registers(SET_POINT1, [0, 5], device_id=125)
        assert code(rr) == ILLEGAL_FUNCTION
        assert code(await client.write_coil(102, True, device_id=125)) == ILLEGAL_FUNCTION
        rr = await client.mask_write_register(
            address=CONTROL_WORD, and_mask=0, or_mask=4, device_id=125
        )
        assert code(rr) == ILLEGAL_FUNCTION
        assert code(await client.write_register(0, 2, device_id=125)) == ILLEGAL_FUNCTION, "NMT"
        assert call(gw, lambda now: sim.get(0x5F0C, 0)) & 0x0004 == 0
        assert gw.image.nodes["display"].health.nmt_state == NmtState.OPERATIONAL
        assert code(await client.read_input_registers(100, count=2, device_id=125)) is None
        assert any("read-only" in r.getMessage() for r in caplog.records)


async def test_a_client_outside_allowed_networks_may_read_but_not_write_and_is_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with running([DISPLAY], modbus={"allowed_networks": ["10.0.0.0/8"]}) as (_, client):
        caplog.set_level(logging.WARNING, logger="gateway.modbus")
        assert code(await client.write_register(CONTROL_WORD, 4, device_id=125)) == ILLEGAL_FUNCTION
        assert code(await client.read_input_registers(100, count=2, device_id=125)) is None
        assert any(
            "127.0.0.1" in r.getMessage() and "allowed_networks" in r.getMessage()
            for r in caplog.records
        )


async def test_a_refused_read_is_logged_in_words_once_a_period_per_client_and_shown_in_the_event_log(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """An off-by-one read (input registers 102-103 of an SGH10, whose process data end at
    102) answers 0x02, and says so: the client, the unit, the function, the range and the
    code, in the log and in the console's event log; the PLC repeating it every cycle gives
    no second line within the period (it is counted)."""
    import json

    from tests.helpers import free_port
    from tests.integration.test_web_http import http

    caplog.set_level(logging.WARNING, logger="gateway.modbus")
    async with running([WIRE], health={"port": free_port()}) as (gw, client):
        for _ in range(3):
            assert code(await client.read_input_registers(102, count=2, device_id=1)) == ILLEGAL_ADDRESS
        assert code(await client.read_holding_registers(0, count=2, device_id=9)) == PATH_UNAVAILABLE
        lines = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
        assert lines == [
            "Modbus read from 127.0.0.1 refused: unit 1, function 4, input registers 102-103: "
            "0x02 (illegal data address): input register 103 of unit 1 is not mapped",
            "Modbus read from 127.0.0.1 refused: unit 9, function 3, holding registers 0-1: "
            "0x0A (gateway path unavailable): unit id 9 is not configured",
        ]
        _, _, body = await http(f"http://127.0.0.1:{gw.health.port}/api/events?kind=warning")
        texts = [e["text"] for e in json.loads(body)["events"]]
        assert any("Modbus read from 127.0.0.1 refused: unit 1, function 4, input registers 102-103" in t for t in texts), texts  # fmt: skip
