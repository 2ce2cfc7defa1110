"""A hot-standby pair of gateways with two CAN networks each, in one process (two virtual buses,
the devices simulated on each; what each gateway sends is recorded at each of its drivers):
each network's pair decides on its own, and what concerns the whole gateway concerns every
network.

* Each network's ``/healthz`` block shows the peer's role as the peer's own heartbeat says it
  (``active``), however old its last claim.
* A gateway that stops (SIGTERM's path: ``Gateway.stop``) hands every network it masters to the
  standby: on each bus its own heartbeat says it stopped mastering and the standby claims at
  once, with no negotiation (no 72h).
* A member that cannot send on one network (its interface there refuses every frame: a full
  transmit queue) stands down on that network only: its bus state ``error``, its role
  ``isolated`` there, its writes to that network's nodes refused; the other member takes that
  network over; the first keeps mastering the other network. Able to send again, it stands by
  there (no fail-back).
"""

from __future__ import annotations

import errno
from typing import Any

import can
import pytest

from canopen_gateway.app import Gateway
from canopen_gateway.config import parse_config
from canopen_gateway.errors import NotActive
from tests.helpers import free_port, gateway_of, simulated_bus, unique_channel, wait_until

LOGICAL = 100
NEGOTIATION_REQUEST = 0x72  # CiA 302-2: starts every master-capable device's time slot


def member_config(pair_id: int, priority: int, peer: int, channels: tuple[str, str]) -> Any:
    def net(name: str, channel: str, node: dict[str, Any]) -> dict[str, Any]:
        return {
            "name": name,
            "can": {"interface": "virtual", "channel": channel},
            "master": {"node_id": LOGICAL, "heartbeat_ms": 100, "heartbeat_timeout_multiple": 3,
                       "sync_period_ms": 0, "boot_timeout_s": 5,
                       "redundancy": {"node_id": pair_id, "priority": priority, "peer_node_id": peer}},
            "nodes": [node],
        }  # fmt: skip

    return parse_config({
        "gateway": {"name": "pair-nets"},
        "networks": [
            net("line1", channels[0], {"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 100}),
            net("line2", channels[1], {"name": "rotary", "node_id": 1, "profile": "posi_plus",
                                       "heartbeat_ms": 100, "modbus": {"unit_id": 101}}),
        ],
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "health": {"port": free_port()},
        "simulate": {"nodes": []},
    }, environ={})  # fmt: skip


def roles(gw: Gateway) -> tuple[str | None, str | None]:
    line1, line2 = gw.networks.all
    return line1.master.role, line2.master.role


class Spy:
    """Every frame one gateway sends, per network (``BusDriver.send`` wrapped), and the role
    changes each network's master reports (role, reason)."""

    def __init__(self, gw: Gateway):
        self.frames: dict[str, list[tuple[int, bytes]]] = {}
        self.changes: dict[str, list[tuple[str, str]]] = {}
        for net in gw.networks:
            sent = self.frames[net.name] = []
            changes = self.changes[net.name] = []
            real = net.driver.send

            def send(cob_id: int, data: bytes = b"", *a: Any, _r: Any = real, _s: Any = sent, **kw: Any) -> None:
                _s.append((cob_id, bytes(data)))
                _r(cob_id, data, *a, **kw)

            net.driver.send = send  # type: ignore[method-assign]
            net.master.role_listeners.append(lambda role, why, _c=changes: _c.append((role, why)))


def refuse_sends(gw: Gateway, network: str) -> can.BusABC:
    """The interface of ``gw`` on ``network`` refuses every frame from now on (ENOBUFS: its
    transmit queue full, as SocketCAN says it); ``del bus.send`` ends it."""
    bus = gw.networks.named(network).driver.bus
    assert bus is not None

    def full(msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("No buffer space available", error_code=errno.ENOBUFS)

    bus.send = full  # type: ignore[method-assign]
    return bus


async def test_a_pair_per_network_hands_every_network_over_at_a_stop_and_stands_down_where_it_cannot_send() -> None:
    channels = (unique_channel(), unique_channel())
    cfg_a = member_config(101, 0, 102, channels)
    cfg_b = member_config(102, 1, 101, channels)
    sim = simulated_bus(cfg_a, ["wire", "rotary"])
    a, b = gateway_of(cfg_a, simulate=False), gateway_of(cfg_b, simulate=False)
    spy_b = Spy(b)
    a2: Gateway | None = None
    try:
        await a.start()
        sim.start()  # the devices power on once A listens: their boot-ups the first frames it hears
        await wait_until(lambda: roles(a) == ("active", "active"), 10, "A active on both")
        await wait_until(lambda: a.image.nodes["rotary"].usable() and a.image.nodes["wire"].usable(), 10, "A's nodes")
        await b.start()
        await wait_until(lambda: roles(b) == ("standby", "standby"), 10, "B standby on both")

        # each network's block: the peer's role as its own heartbeat says it, whatever its claim's age
        def old_claims() -> dict[str, Any] | None:
            doc = b.status()
            return doc if all((n["peer"]["claim_age_s"] or 0) > 0.3 for n in doc["networks"].values()) else None

        doc = await wait_until(old_claims, 10, "A's claims older than a take-over")
        assert {n: (v["role"], v["peer"]["role"]) for n, v in doc["networks"].items()} == {
            "line1": ("standby", "active"), "line2": ("standby", "active")}  # fmt: skip
        doc = a.status()
        assert {n: v["peer"]["role"] for n, v in doc["networks"].items()} == {"line1": "standby", "line2": "standby"}

        # a stop hands every network over: B claims on each at once, no negotiation
        for net in ("line1", "line2"):
            spy_b.frames[net].clear()
        await a.stop()
        await wait_until(lambda: roles(b) == ("active", "active"), 5, "B active on both")
        for net in ("line1", "line2"):
            assert any(role == "active" and "handed the bus over" in why for role, why in spy_b.changes[net]), (
                spy_b.changes[net])  # fmt: skip
            assert NEGOTIATION_REQUEST not in {c for c, _ in spy_b.frames[net]}

        # A back: standby on both; then B cannot send on line2
        a2 = gateway_of(cfg_a, simulate=False)
        await a2.start()
        await wait_until(lambda: roles(a2) == ("standby", "standby"), 10, "A back, standby on both")
        bus = refuse_sends(b, "line2")
        try:
            await wait_until(lambda: roles(b) == ("active", "isolated"), 5, "B stands down on line2 only")
            line2 = b.status()["networks"]["line2"]
            assert line2["bus"]["state"] == "error" and "transmit queue full" in line2["bus"]["detail"]
            with pytest.raises(NotActive):
                b.networks.require_active("rotary")  # its writes to line2's node refused
            b.networks.require_active("wire")  # line1 goes on
            await wait_until(lambda: roles(a2) == ("standby", "active"), 5, "A takes line2 over")
        finally:
            del bus.send
        await wait_until(lambda: roles(b) == ("active", "standby"), 5, "B sends again: standby on line2")
        assert roles(a2) == ("standby", "active")  # no fail-back
        assert b.status()["networks"]["line2"]["bus"]["state"] == "ok"
    finally:
        if a2 is not None:
            await a2.stop()
        await b.stop()
        if a.started:
            await a.stop()
        sim.stop()
