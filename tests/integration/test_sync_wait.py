"""SYNC-driven TPDOs without a SYNC producer, against a simulated SGH10 on a virtual bus: with
TPDO1 off its position and velocity come only in TPDO2 (every SYNC, SGH10 manual 4.3); with
``master.sync_period_ms`` 0 the device never sends it, and the node's ``last_error`` says why
its values are bad; with the SYNC producer on, the same node serves them."""

from __future__ import annotations

from canopen_gateway.bus.node.features.sync_wait import WAITING
from canopen_gateway.image import Quality
from tests.helpers import master_running as running
from tests.helpers import node_operational as operational
from tests.helpers import wait_until

SYNC_ONLY = [{"name": "wire", "node_id": 1, "profile": "sgh10", "tpdo": {1: {"enabled": False}}}]


async def test_a_node_waiting_for_sync_driven_tpdos_says_so_and_its_values_stay_bad() -> None:
    async with running(SYNC_ONLY, master={"sync_period_ms": 0}) as gw:
        await wait_until(lambda: operational(gw, "wire"), 10, "wire operational")
        node = gw.image.nodes["wire"]
        assert node.health.last_error.startswith(f"{WAITING} (TPDO2 carries position, velocity")
        assert node.quality(node.signals["position"]) is Quality.BAD


async def test_with_a_sync_producer_the_same_node_serves_its_values() -> None:
    async with running(SYNC_ONLY, master={"sync_period_ms": 20}) as gw:
        node = gw.image.nodes["wire"]
        await wait_until(lambda: operational(gw, "wire") and node.signals["position"].seq > 0, 10, "position")
        assert node.health.last_error == ""
        assert node.quality(node.signals["position"]) is Quality.GOOD
