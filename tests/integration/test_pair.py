"""A hot-standby pair on one virtual bus: two gateways of one config (each with its own id in
the pair) and a simulated SGH10. The active one masters the bus; the standby only listens and
keeps the same image; when the active one falls silent the standby takes the bus over without
the device noticing (no NMT command, no SDO, values good throughout).

What each gateway sends is recorded at its own driver (a virtual bus cannot say who sent a
frame); the device's frames are read from a third connection.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import can
import pytest

from canopen_gateway.app import Gateway
from canopen_gateway.config import parse_config
from canopen_gateway.errors import NotActive
from canopen_gateway.image import Quality
from canopen_gateway.sim.buses import SimulatedBus
from tests.helpers import gateway_of, make_config, node_operational, simulated_bus, wait_until

LOGICAL = 100
HB_MS = 100


def pair_configs(wire: dict[str, Any] | None = None) -> tuple[Any, Any]:
    """The pair's two configs: the SGH10 ``wire`` (with these keys more) and an AP05."""
    base = make_config(
        [
            {"name": "wire", "node_id": 1, "profile": "sgh10", **(wire or {})},
            {"name": "display", "node_id": 2, "profile": "ap05"},
        ],
        master={"node_id": LOGICAL, "heartbeat_ms": HB_MS, "sync_period_ms": 0},
        modbus={"enabled": False},
        zenoh={"enabled": False},
    )
    raw = base.model_dump(exclude_none=True)
    raw["simulate"] = {"nodes": []}
    return member_configs(raw)


def member_configs(raw: dict[str, Any]) -> tuple[Any, Any]:
    """One raw config as the pair's two members: A (pair id 101, priority 0) and B (102, 1)."""
    a = {**raw, "master": {**raw["master"], "redundancy": {"node_id": 101, "priority": 0}}}
    b = {**raw, "master": {**raw["master"], "redundancy": {"node_id": 102, "priority": 1}}}
    return parse_config(a, environ={}), parse_config(b, environ={})


class Sent:
    """Every frame one gateway's driver sends (a spy on ``BusDriver.send``)."""

    def __init__(self, gw: Gateway):
        self.frames: list[tuple[int, bytes]] = []
        self.silent = False
        real = gw.driver.send

        def send(cob_id: int, data: bytes, **kw: Any) -> None:
            if self.silent:  # killed: nothing leaves this gateway any more
                return
            self.frames.append((cob_id, bytes(data)))
            real(cob_id, data, **kw)

        gw.driver.send = send  # type: ignore[method-assign]

    def cob_ids(self) -> set[int]:
        return {c for c, _ in self.frames}

    def count(self, cob_id: int) -> int:
        return sum(1 for c, _ in self.frames if c == cob_id)


@asynccontextmanager
async def pair_running(
    cfgs: tuple[Any, Any] | None = None, *, standby: bool = False
) -> AsyncIterator[tuple[Gateway, Gateway, Sent, Sent, SimulatedBus]]:
    """A started, B started after A configured the devices (``standby``: and until B stands
    by); ``cfgs``: the pair's two configs (default ``pair_configs()``)."""
    cfg_a, cfg_b = cfgs if cfgs is not None else pair_configs()
    sim = simulated_bus(cfg_a, names=["wire", "display"])
    a, b = gateway_of(cfg_a, simulate=False), gateway_of(cfg_b, simulate=False)
    sent_a, sent_b = Sent(a), Sent(b)
    try:
        await a.start()
        # the devices power on once A listens: their boot-ups are the first frames it hears (on a
        # bus silent from its start a first master waits 2 s before it claims the bus)
        sim.start()
        for name in ("wire", "display"):
            await wait_until(lambda n=name: node_operational(a, n), 10, f"A configures {name}")
        await b.start()
        if standby:
            await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        yield a, b, sent_a, sent_b, sim
    finally:
        await b.stop()
        await a.stop()
        sim.stop()


def position_good(gw: Gateway) -> bool:
    node = gw.image.nodes["wire"]
    return node.quality(node.signals["position"]) is Quality.GOOD


async def test_the_first_gateway_masters_the_bus_and_the_second_only_listens() -> None:
    async with pair_running() as (a, b, sent_a, sent_b, _sim):
        assert a.master.role == "active" and a.master.mastering
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        await wait_until(lambda: position_good(b), 5, "B serves the position good")
        assert b.image.nodes["wire"].health.alive
        # B sent its detection request and its own heartbeat, nothing else
        assert sent_b.cob_ids() <= {0x73, 0x700 + 102}
        assert sent_b.count(0x73) == 1
        assert 0x000 not in sent_b.cob_ids() and 0x601 not in sent_b.cob_ids()
        # A claimed: it answered B's request
        assert sent_a.count(0x71) >= 1
        with pytest.raises(NotActive):
            b.master.nmt("wire", "start")


async def test_a_write_through_the_active_one_is_the_standbys_output_too() -> None:
    async with pair_running() as (a, b, _sent_a, _sent_b, _sim):
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        node_a = a.master.nodes["display"].node
        name = node_a.rpdos[0].names[0]
        a.master.write_outputs("display", {None: {name: 7}})
        node_b = b.master.nodes["display"].node
        await wait_until(lambda: node_b.output(name) == 7, 5, "B heard the RPDO")
        await wait_until(
            lambda: b.image.nodes["display"].outputs.rpdos[1]
            == a.image.nodes["display"].outputs.rpdos[1],
            5,
            "B's RPDO1 is A's as sent (the guarding bit included)",
        )


async def test_the_standby_takes_over_when_the_active_one_falls_silent() -> None:
    async with pair_running() as (a, b, sent_a, sent_b, sim):
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        await wait_until(lambda: position_good(b), 5, "B good")
        a.master.write_outputs("display", {None: {"set_point2": 4321}})  # RPDO2 (302h)
        node_b = b.master.nodes["display"].node
        await wait_until(lambda: node_b.output("set_point2") == 4321, 5, "B heard RPDO2")
        sent_a.silent = True  # A dies: not one more frame
        a.master.mastering = False  # and it does nothing more of its own
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        assert b.master.pair is not None and b.master.pair.takeovers == 1
        await wait_until(lambda: sent_b.count(0x700 + LOGICAL) >= 3, 5, "B's logical heartbeat")
        # the device was adopted as it runs: no NMT command, no SDO download from B
        assert 0x000 not in sent_b.cob_ids()
        assert not [d for c, d in sent_b.frames if c == 0x601 and d[0] >> 5 == 1]
        for name in ("wire", "display"):
            assert node_operational(b, name)
            assert sim.nodes[name].nmt_state == 0x05  # the devices stayed OPERATIONAL
        assert position_good(b)
        # a write through B: the control word goes out in RPDO2 with the set point A had sent
        b.master.write_outputs("display", {None: {"control_word": 0}})
        rpdo2 = [d for c, d in sent_b.frames if c == 0x302]
        assert rpdo2 and int.from_bytes(rpdo2[-1][0:4], "little", signed=True) == 4321
        b.master.nmt("wire", "start")  # commands are B's now


async def test_a_detection_of_master_capable_devices_is_answered_by_each_member_not_logged() -> None:
    async with pair_running() as (a, b, sent_a, sent_b, _sim):
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        unknown = (a.image.counters["unknown_cob_id"], b.image.counters["unknown_cob_id"])
        probe = can.Bus(**a.cfg.can.bus_kwargs())  # a commissioning tool on the same bus
        try:
            probe.send(can.Message(arbitration_id=0x75, data=b"", is_extended_id=False))
            await wait_until(lambda: sent_a.count(0x74) == 1 and sent_b.count(0x74) == 1, 5,
                             "74h from each member")  # fmt: skip
        finally:
            probe.shutdown()
        assert (0x74, bytes((0, 101))) in sent_a.frames and (0x74, bytes((1, 102))) in sent_b.frames
        assert (a.image.counters["unknown_cob_id"], b.image.counters["unknown_cob_id"]) == unknown
