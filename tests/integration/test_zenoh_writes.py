"""Who may write through Zenoh: ``zenoh.writes`` off by default (every set, SDO download and NMT
answered ``forbidden``, nothing on the bus, counted in /metrics), on with allow-lists by
operation, node and key expression; reads stay open. A listener on the gateway's virtual CAN
bus sees every frame the gateway sends, so "nothing on the bus" is checked frame by frame."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import can

from canopen_gateway.app import Gateway
from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.integration.test_diagnostics import metric, scrape
from tests.zenoh_client import ZClient

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}
P = "canopen/test"
SDO_RX_WIRE = 0x601  # DS-301: SDO client -> server of node 1
NMT_COB = 0x000
SET_POINT = 4321
SET_POINT_BYTES = SET_POINT.to_bytes(4, "little")


@asynccontextmanager
async def gateway(zenoh: dict[str, Any]) -> AsyncIterator[tuple[Gateway, ZClient, can.BusABC]]:
    cfg = make_config(
        [WIRE, DISPLAY],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        health={"port": free_port()},
        zenoh=zenoh,
    )
    gw = gateway_of(cfg)
    await gw.start()
    z = ZClient(cfg.zenoh.listen)
    bus: can.BusABC | None = None
    try:
        for name in ("wire", "display"):
            await wait_until(lambda n=name: gw.image.nodes[n].usable(), 8, f"{name} usable")
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)  # from here on: every frame
        yield gw, z, bus
    finally:
        if bus is not None:
            bus.shutdown()
        z.close()
        await gw.stop()


def frames(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(0)) is not None:
        out.append(m)
    return out


def sdo_downloads(msgs: list[can.Message], cob: int = SDO_RX_WIRE) -> list[can.Message]:
    """SDO initiate-download requests (DS-301 7.2.4.3.3: ccs 1 in the top three bits)."""
    return [m for m in msgs if m.arbitration_id == cob and m.data and m.data[0] >> 5 == 1]


def nmt_frames(msgs: list[can.Message]) -> list[can.Message]:
    return [m for m in msgs if m.arbitration_id == NMT_COB]


def carries_set_point(msgs: list[can.Message]) -> bool:
    return any(SET_POINT_BYTES in bytes(m.data) for m in msgs if 0x200 <= m.arbitration_id < 0x580)


def sim_value(gw: Gateway, node: str, index: int, sub: int) -> Any:
    assert gw.sim is not None
    return gw.sim.runner.call(lambda now: gw.sim.nodes[node].get(index, sub))


async def test_writes_are_off_by_default_forbidden_counted_and_nothing_reaches_the_bus() -> None:
    async with gateway({}) as (gw, z, bus):
        before_6000 = sim_value(gw, "wire", 0x6000, 0)
        refused = [
            (f"{P}/display/set/set_point2", str(SET_POINT)),
            (f"{P}/display/set", f'{{"set_point2": {SET_POINT}}}'),
            (f"{P}/wire/set/operating_parameters", '{"bits": {"counting_direction_descending": true}}'),
            (f"{P}/wire/sdo/6000/00", "8"),
            (f"{P}/wire/nmt", "stop"),
            (f"{P}/wire/nmt", "jump"),  # refused before it is even parsed
            (f"{P}/ghost/nmt", "stop"),
        ]
        for selector, payload in refused:
            r = await z.get_one(selector, payload=payload)
            assert not r.ok, (selector, r.body)
            assert r.body["error"] == "forbidden", (selector, r.body)
            assert "zenoh.writes: on" in r.body["message"] and r.body["key"] == selector

        # reads stay open: SDO upload, state, value, catalogue
        up = await z.get_one(f"{P}/wire/sdo/1008/00")
        assert up.ok and up.body["value"] == "SGH10"
        st = await z.get_one(f"{P}/wire/state")
        assert st.ok and st.body["nmt_state"] == "operational"
        cat = await z.get_one(f"{P}/catalog")
        assert cat.ok and cat.body["writes"] is False

        # a write through the command service (Modbus's way) goes out: the bus listener works
        await gw.commands.write_signal("display", "set_point2", SET_POINT + 1)
        await wait_until(lambda: sim_value(gw, "display", 0x5F16, 1) == SET_POINT + 1, 3, "5F16h")
        sent = frames(bus)
        assert any((SET_POINT + 1).to_bytes(4, "little") in bytes(m.data) for m in sent)
        assert not carries_set_point(sent)
        assert sdo_downloads(sent) == [] and nmt_frames(sent) == []
        assert sim_value(gw, "wire", 0x6000, 0) == before_6000
        assert gw.image.nodes["wire"].health.nmt_state.name == "OPERATIONAL"

        m = await scrape(gw)
        assert metric(m, "zenoh_refused_total", operation="set") == 3
        assert metric(m, "zenoh_refused_total", operation="sdo_write") == 1
        assert metric(m, "zenoh_refused_total", operation="nmt") == 3


async def test_refusals_are_logged_once_per_period_not_per_request(caplog: Any) -> None:
    async with gateway({}) as (gw, z, bus):
        caplog.clear()
        for _ in range(20):
            r = await z.get_one(f"{P}/wire/nmt", payload="stop")
            assert not r.ok and r.body["error"] == "forbidden"
        lines = [r for r in caplog.records if "refused" in r.getMessage()]
        assert len(lines) == 1, [r.getMessage() for r in lines]
        assert gw.zenoh is not None and gw.zenoh.refused == {"nmt": 20}
        assert nmt_frames(frames(bus)) == []


async def test_allow_lists_by_operation_node_and_key_expression() -> None:
    zenoh = {
        "writes": True,
        "write_allow": [
            # the display's set points only (not its control word), by key expression
            {"operations": ["set"], "nodes": ["display"], "keys": [f"{P}/display/set/set_point$*"]},
            # SDO downloads to the wire sensor's 6000h only
            {"operations": ["sdo_write"], "keys": [f"{P}/wire/sdo/6000/**"]},
        ],
    }
    async with gateway(zenoh) as (gw, z, bus):
        ok = await z.get_one(f"{P}/display/set/set_point2", payload=str(SET_POINT))
        assert ok.ok, ok.body
        await wait_until(lambda: sim_value(gw, "display", 0x5F16, 1) == SET_POINT, 3, "5F16h:01")
        sdo = await z.get_one(f"{P}/wire/sdo/6000/00", payload="4")
        assert sdo.ok, sdo.body

        sent_allowed = frames(bus)
        assert carries_set_point(sent_allowed)
        assert len(sdo_downloads(sent_allowed)) == 1

        for selector, payload in [
            (f"{P}/display/set/control_word", "0"),  # key not in the rule
            (f"{P}/display/set", '{"set_point2": 1}'),  # set_many key not in the rule
            (f"{P}/wire/sdo/6010/01", "5"),  # other object
            (f"{P}/display/sdo/5f16/01", "5"),  # other node's objects
            (f"{P}/wire/set/operating_parameters", "4"),  # set not allowed on wire
            (f"{P}/wire/nmt", "stop"),  # nmt in no rule
        ]:
            r = await z.get_one(selector, payload=payload)
            assert not r.ok and r.body["error"] == "forbidden", (selector, r.body)
            assert "zenoh.write_allow" in r.body["message"]
        await asyncio.sleep(0)  # nothing to wait for: refusals happen before the bus
        sent = frames(bus)
        assert sdo_downloads(sent) == [] and sdo_downloads(sent, 0x600 + 125) == []
        assert nmt_frames(sent) == []
        assert gw.zenoh is not None
        assert gw.zenoh.refused == {"set": 3, "sdo_write": 2, "nmt": 1}


async def test_bits_of_an_sdo_word_are_written_read_modify_write_on_the_simulated_sgh10() -> None:
    """SGH10 6000h (operating parameters, manual 4.7.2.23): bit 3 counting direction is
    writable, bit 2 scaling stays as the device has it."""
    async with gateway({"writes": True}) as (gw, z, bus):
        start = sim_value(gw, "wire", 0x6000, 0)
        assert start & 0x4 and not start & 0x8  # factory 0004h
        r = await z.get_one(
            f"{P}/wire/set/operating_parameters",
            payload='{"bits": {"counting_direction_descending": true}}',
        )
        assert r.ok, r.body
        assert r.body["via"] == "sdo"
        assert sim_value(gw, "wire", 0x6000, 0) == start | 0x8
        back = await z.get_one(
            f"{P}/wire/set/operating_parameters",
            payload='{"bits": {"counting_direction_descending": false}}',
        )
        assert back.ok and sim_value(gw, "wire", 0x6000, 0) == start
        sent = frames(bus)
        # two read-modify-writes: an upload then a download each
        assert len(sdo_downloads(sent)) == 2
        refused = await z.get_one(
            f"{P}/wire/set/operating_parameters", payload='{"bits": {"scaling_enabled": false}}'
        )
        assert not refused.ok and refused.body["error"] == "bad_request"
        assert sim_value(gw, "wire", 0x6000, 0) == start
