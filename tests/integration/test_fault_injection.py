"""Fault injection into a running gateway's simulated node, seen the way a user sees it: through
a real Modbus client (pymodbus over TCP), a real Zenoh session on loopback and the web console's
HTTP API. Unplugged, the node's values answer Modbus exception 0x0B and Zenoh quality "stale",
and the console says "lost"; plugged back (the device restarts), everything is good again once
the gateway has started it. A stopped heartbeat makes the node lost while its PDOs still arrive;
its last_error says why at once; a raised EMCY reaches the console's current errors and the event log."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from tests.helpers import free_port, gateway_of, make_config, node_operational, wait_until
from tests.integration.test_web_http import http
from tests.zenoh_client import ZClient

NO_RESPONSE = 0x0B  # Modbus: gateway target device failed to respond


@asynccontextmanager
async def demo() -> AsyncIterator[tuple[Gateway, str, AsyncModbusTcpClient, ZClient]]:
    cfg = make_config(
        [
            {"name": "wire", "node_id": 1, "profile": "sgh10"},
            {"name": "display", "node_id": 125, "profile": "ap05"},
        ],
        health={"port": free_port()},
    )
    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    await client.connect()
    z = ZClient(cfg.zenoh.listen)
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        yield gw, f"http://127.0.0.1:{gw.health.port}", client, z
    finally:
        client.close()
        z.close()
        await gw.stop()


async def fault(base: str, node: str, action: str) -> dict[str, Any]:
    code, _, body = await http(f"{base}/api/sim/{node}/{action}", {}, method="POST")
    assert code == 200, body
    return json.loads(body)


async def console_row(base: str, node: str) -> dict[str, Any]:
    code, _, body = await http(f"{base}/api/node/{node}")
    assert code == 200
    return json.loads(body)["row"]


async def modbus_position(client: AsyncModbusTcpClient) -> int | None:
    """The exception code of a read of wire's position (input registers 100-101), or None."""
    rr = await client.read_input_registers(100, count=2, device_id=1)
    return rr.exception_code if rr.isError() else None


async def test_unplugged_node_is_lost_everywhere_and_good_again_after_it_restarts() -> None:
    async with demo() as (gw, base, client, z):
        prefix = gw.zenoh.prefix
        await wait_until(
            lambda: gw.web.model.values("wire")["position"]["quality"] == "good", 5, "good"
        )
        assert await modbus_position(client) is None
        health = gw.image.nodes["wire"].health
        boots = health.boot_count

        await fault(base, "wire", "unplug")
        await wait_until(lambda: not health.alive, 5, "wire lost")
        assert await modbus_position(client) == NO_RESPONSE
        reply = await z.get_one(f"{prefix}/wire/value/position")
        assert reply.ok and reply.body["quality"] == "stale"
        row = await console_row(base, "wire")
        assert row["presence"] == "lost" and row["quality"] == "stale"
        assert (await console_row(base, "display"))["presence"] == "alive"  # only that node

        await fault(base, "wire", "plug")
        await wait_until(lambda: health.boot_count == boots + 1, 5, "the boot-up")
        await wait_until(lambda: node_operational(gw, "wire"), 5, "started again")
        await wait_until(
            lambda: gw.web.model.values("wire")["position"]["quality"] == "good", 5, "fresh"
        )
        assert await modbus_position(client) is None
        reply = await z.get_one(f"{prefix}/wire/value/position")
        assert reply.ok and reply.body["quality"] == "good"
        row = await console_row(base, "wire")
        assert row["presence"] == "alive" and row["quality"] == "good"


async def test_a_stopped_heartbeat_makes_the_node_lost_although_its_pdos_continue() -> None:
    async with demo() as (gw, base, client, z):
        node = gw.image.nodes["wire"]
        await fault(base, "wire", "heartbeat-off")
        await wait_until(lambda: not node.health.alive, 5, "wire lost")
        seq = node.signals["position"].seq
        await wait_until(lambda: node.signals["position"].seq > seq, 5, "a PDO after the loss")
        assert await modbus_position(client) == NO_RESPONSE
        row = await console_row(base, "wire")
        assert row["presence"] == "lost"
        # why, from the loss on (not after a boot timeout): /healthz, the Zenoh state, the console
        why = row["last_error"]
        assert why.startswith("lost (no heartbeat for more than ") and why.endswith(" ms)"), why
        _, _, body = await http(f"{base}/healthz")
        assert json.loads(body)["nodes"]["wire"]["last_error"] == why
        reply = await z.get_one(f"{gw.zenoh.prefix}/wire/state")
        assert reply.ok and reply.body["last_error"] == why
        doc = await fault(base, "wire", "heartbeat-on")
        assert doc["state"]["heartbeat"] is True
        await wait_until(lambda: node_operational(gw, "wire"), 5, "operational again")


async def test_a_raised_emcy_reaches_the_console_and_the_event_log() -> None:
    async with demo() as (gw, base, client, z):
        doc = await fault(base, "wire", "emcy")
        code = doc["state"]["emcy"].split()[0]  # the profile's fault (sensor error)
        health = gw.image.nodes["wire"].health
        await wait_until(lambda: health.current_errors, 5, "an active error")
        code_of = f"0x{health.current_errors[0]:04X}"
        assert code_of == code
        _, _, body = await http(base + "/api/node/wire")
        assert [c["code"] for c in json.loads(body)["emcy"]["current"]] == [code]
        _, _, body = await http(base + "/api/events?kind=emcy&node=wire")
        assert json.loads(body)["events"][-1]["text"].startswith(f"wire: EMCY {code}")
        await fault(base, "wire", "emcy-clear")
        await wait_until(lambda: not health.current_errors, 5, "the error cleared")


async def test_the_event_log_says_where_a_fault_came_from() -> None:
    """The command line (``canopen-gateway fault``), the console's page (its header) and any
    other HTTP client are each named as what they are."""
    import asyncio
    import urllib.request

    from canopen_gateway.sim.faults_client import run_fault

    async with demo() as (gw, base, _, _):
        assert await asyncio.to_thread(run_fault, gw.cfg, "wire", "heartbeat-off", base) == 0
        req = urllib.request.Request(
            f"{base}/api/sim/wire/heartbeat-on",
            data=b"{}",
            method="POST",
            headers={"Content-Type": "application/json", "X-Canopen-Client": "console"},
        )
        await asyncio.to_thread(lambda: urllib.request.urlopen(req, timeout=5).close())
        await fault(base, "wire", "emcy")
        _, _, body = await http(base + "/api/events?kind=warning&node=wire")
        texts = [e["text"] for e in json.loads(body)["events"]]
    assert "simulated fault: wire heartbeat-off (from web 127.0.0.1, canopen-gateway fault as its client says)" in texts
    assert "simulated fault: wire heartbeat-on (from web 127.0.0.1, the web console as its client says)" in texts
    assert "simulated fault: wire emcy (from web 127.0.0.1, the HTTP API)" in texts
