"""Two CAN networks in one in-process gateway (two virtual buses, the devices simulated on each):
one Network per bus, each with its driver, master and threads; what is shown north names each
network: /healthz, the metrics' ``network`` label, unit 247's registers per network, the
catalogue, a node's state, the audit; the command service routes by node name to the node's
network."""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.journal import Journal
from canopen_gateway.northbound.gateway_block import (
    NETWORK_BUS_STATE,
    NETWORK_PAIR_ROLE,
    NETWORKS_REGISTER,
)
from canopen_gateway.zenoh_bridge.payloads import state_payload
from tests.helpers import (
    free_port,
    modbus_gateway,
    parse_checked_config,
    unique_channel,
    wait_until,
)


def two_networks(**sections: Any) -> Any:
    def net(name: str, node: dict[str, Any]) -> dict[str, Any]:
        return {"name": name, "can": {"interface": "virtual", "channel": unique_channel()},
                "master": {"heartbeat_ms": 200, "heartbeat_timeout_multiple": 3}, "nodes": [node]}  # fmt: skip

    return parse_checked_config({
        "gateway": {"name": "t"},
        "networks": [net("line1", {"name": "wire", "node_id": 1, "profile": "sgh10"}),
                     net("line2", {"name": "rotary", "node_id": 1, "profile": "posi_plus",
                                   "modbus": {"unit_id": 101}})],
        "modbus": {"port": free_port()},
        "zenoh": {"enabled": False},
        "health": {"port": free_port()},
        "simulate": {"nodes": "all"},
        **sections,
    }, environ={})  # fmt: skip


def good(name: str) -> Any:
    return lambda gw: gw.image.nodes[name].usable()


async def test_each_network_has_its_own_bus_threads_and_master_and_is_named_north(
    caplog: pytest.LogCaptureFixture,
) -> None:
    cfg = two_networks()
    caplog.set_level(logging.INFO, logger="gateway.master")
    async with modbus_gateway(cfg, [(good("wire"), "wire"), (good("rotary"), "rotary")]) as (gw, client):
        # a node's log lines name its network, as the bus's do (node 1 is on both)
        said = [r.getMessage() for r in caplog.records]
        assert any(m.startswith("node rotary (id 1)") and m.endswith("(network line2)") for m in said), said
        assert not any(m.startswith("node wire") and "line2" in m for m in said)
        line1, line2 = gw.networks.all
        assert (line1.name, line2.name, line1.number, line2.number) == ("line1", "line2", 1, 2)
        assert line1.driver is not line2.driver and line1.master is not line2.master
        names = {t.name for t in threading.enumerate()}
        assert {"can-reader-line1", "can-reader-line2", "can-sender-line1", "can-sender-line2"} <= names
        assert gw.commands.network_of("rotary") == "line2"

        status = gw.status()
        assert status["ready"] and set(status["networks"]) == {"line1", "line2"}
        assert status["networks"]["line2"]["bus"] == {"state": "ok", "detail": ""}
        assert status["networks"]["line2"]["nodes"] == ["rotary"]
        assert state_payload(gw.image.nodes["rotary"])["network"] == "line2"
        assert gw.catalog()["nodes"]["rotary"]["network"] == "line2"

        r = await client.read_input_registers(NETWORKS_REGISTER, count=1, device_id=247)
        states = await client.read_input_registers(NETWORK_BUS_STATE, count=2, device_id=247)
        roles = await client.read_input_registers(NETWORK_PAIR_ROLE, count=2, device_id=247)
        assert (r.registers, states.registers, roles.registers) == ([2], [1, 1], [0, 0])

        reader, writer = await asyncio.open_connection("127.0.0.1", gw.health.port)
        writer.write(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
        text = (await reader.read()).decode()
        writer.close()
        assert 'canopen_gateway_can_bus_state{network="line1"} 1.0' in text
        assert 'canopen_gateway_can_bus_state{network="line2"} 1.0' in text
        assert 'canopen_gateway_can_frames_in_total{network="line2"}' in text


async def test_nmt_to_all_of_one_network_reaches_only_its_nodes_and_the_audit_names_it(
    tmp_path: Path,
) -> None:
    cfg = two_networks(journal={"path": str(tmp_path / "j")})
    async with modbus_gateway(cfg, [(good("wire"), "wire"), (good("rotary"), "rotary")]) as (gw, _):
        await gw.commands.nmt("all", "stop", "line2")  # one broadcast (node id 0) on line2's bus
        await wait_until(lambda: not gw.image.nodes["rotary"].operational(), 5, "rotary stopped")
        assert gw.image.nodes["wire"].operational()
        await gw.commands.nmt("rotary", "start")

        def audited() -> list[dict[str, Any]]:
            return [json.loads(r.payload) for r in Journal(tmp_path / "j").read(kinds=["audit"])]

        await wait_until(lambda: any(a["node"] == "rotary" for a in audited()), 5, "the audit")
        assert next(a for a in audited() if a["node"] == "rotary")["network"] == "line2"
        assert next(a for a in audited() if a["node"] == "all")["network"] == "line2"
