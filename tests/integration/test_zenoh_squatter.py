"""A participant that announces our prefix (its liveliness token ``<prefix>/alive/_gateway``)
cannot keep the gateway from starting: Modbus, the CAN master and the console run, ``/healthz``
answers 503 naming zenoh and why, and the gateway joins once the squatter is gone. With several
CAN networks the squatter's reason stands beside a network's own in the one ``reasons`` list."""

from __future__ import annotations

import asyncio
import json
import urllib.error
import urllib.request

import pytest
import zenoh

from canopen_gateway.zenoh_bridge import session as zenoh_session
from tests.helpers import (
    free_port,
    make_config,
    modbus_gateway,
    parse_checked_config,
    unique_channel,
    wait_until,
)
from tests.zenoh_client import open_router, session_config

WIRE = [{"name": "wire", "node_id": 1, "profile": "sgh10"}]


def healthz(port: int) -> tuple[int, dict]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=3) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


@pytest.mark.parametrize("mode", ["client", "peer"])
async def test_a_squatted_prefix_starts_the_gateway_without_zenoh_and_it_joins_once_free(
    mode: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(zenoh_session, "REOPEN_SCHEDULE_S", (0.2,))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    squatter = zenoh.open(session_config("client", connect=[endpoint]))
    token = squatter.liveliness().declare_token("canopen/test/alive/_gateway")
    health = free_port()
    cfg = make_config(
        WIRE,
        zenoh={"mode": mode, "connect": [endpoint]},  # a peer listens on its own port too
        health={"port": health},
    )
    try:
        async with modbus_gateway(cfg) as (gw, plc):
            assert gw.zenoh is not None and not gw.zenoh.up
            rr = await plc.read_input_registers(0, count=2, device_id=1)
            assert not rr.isError()  # the PLC side serves
            code, doc = await asyncio.to_thread(healthz, health)
            assert code == 503
            assert any(r.startswith("zenoh: another participant announces a gateway under "
                                    "Zenoh prefix canopen/test") for r in doc["reasons"]), doc
            token.undeclare()
            await wait_until(lambda: gw.zenoh.up, 10, "the gateway's Zenoh session")
            code, doc = await asyncio.to_thread(healthz, health)
            assert code == 200 and doc["zenoh"] is True
    finally:
        squatter.close()
        router.close()


async def test_a_squatted_prefix_and_a_network_down_are_both_reasons_of_one_list(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(zenoh_session, "REOPEN_SCHEDULE_S", (0.2,))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    squatter = zenoh.open(session_config("client", connect=[endpoint]))
    token = squatter.liveliness().declare_token("canopen/two/alive/_gateway")
    health = free_port()
    cfg = parse_checked_config({
        "gateway": {"name": "two"},
        "networks": [
            {"name": "line1", "can": {"interface": "virtual", "channel": unique_channel()},
             "master": {"heartbeat_ms": 200, "heartbeat_timeout_multiple": 3}, "nodes": WIRE},
            # a port whose bus does not open here: line2 stays down
            {"name": "line2", "can": {"interface": "socketcan", "channel": "nosuchcan9"},
             "nodes": [{"name": "rotary", "node_id": 5, "profile": "posi_plus"}]},
        ],
        "modbus": {"port": free_port()},
        "zenoh": {"mode": "client", "connect": [endpoint]},
        "health": {"port": health},
        "simulate": {"nodes": ["wire"]},
    }, environ={})  # fmt: skip
    try:
        async with modbus_gateway(cfg, [(lambda gw: gw.image.nodes["wire"].usable(), "wire")]) as (gw, plc):
            rr = await plc.read_input_registers(0, count=2, device_id=1)
            assert not rr.isError()  # line1's node is served
            code, doc = await asyncio.to_thread(healthz, health)
            assert code == 503
            assert any(r.startswith("network line2: CAN bus down") for r in doc["reasons"]), doc
            assert any(r.startswith("zenoh: another participant announces a gateway under "
                                    "Zenoh prefix canopen/two") for r in doc["reasons"]), doc
            token.undeclare()
            await wait_until(lambda: gw.zenoh.up, 10, "the gateway's Zenoh session")
            code, doc = await asyncio.to_thread(healthz, health)
            assert code == 503 and doc["zenoh"] is True
            assert [r.split(":")[0] for r in doc["reasons"]] == ["network line2"]
    finally:
        squatter.close()
        router.close()
