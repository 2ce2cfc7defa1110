"""A hot-standby pair against an independent device stack: python canopen's LocalNode (built
from the POSI+ EDS) answers the active gateway's SDO boot steps from its own dictionary, among
them 1016h:01, the consumer of the logical master's heartbeat (CiA 301 7.5.2.15: producer id in
bits 16..23, consumer time in ms in bits 0..15). The test sends the device's heartbeat and
TPDO1 itself.

Through the take-over (the active gateway falls silent, the standby takes the bus over) the
logical heartbeat the device consumes never pauses longer than its consumer time: the gaps
are measured between bus timestamps of the logical heartbeats a listener received (a protocol
property of the frames, not a wall-clock wait). Every logical heartbeat carries OPERATIONAL, and
no NMT command, SDO request or 1016h write reaches the device from the new active gateway.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import can
import canopen

from canopen_gateway.app import Gateway
from canopen_gateway.image import Quality
from tests.helpers import gateway_of, make_config, node_operational, wait_until
from tests.integration.test_eds_devices import Heartbeat, boot, local_node
from tests.integration.test_pair import Sent, member_configs

EDS = Path(__file__).resolve().parents[2] / "canopen_gateway" / "profiles" / "posi_plus.eds"
NODE_ID = 3
LOGICAL = 100
HB_MS = 100
#: the device's consumer time for the logical master: the take-over with the defaults
#: (docs/redundancy.md "Take-over": 300 ms + B's slot 1 x 200 + 102 x 2 ms, plus at most one
#: heartbeat period) must fit, so that the device never reports a heartbeat loss (EMCY 8130h)
CONSUMER_MS = 1000
# CiA 301 7.5.2.15: 1016h:01 = producer node id << 16 | consumer heartbeat time (ms)
CONSUMER_1016 = (LOGICAL << 16) | CONSUMER_MS


class LogicalHeartbeats(can.Listener):
    """Bus timestamps and states of the logical master's heartbeat, and every NMT command and
    SDO request to the device, as a third connection on the bus hears them."""

    def __init__(self) -> None:
        self.heartbeats: list[tuple[float, int]] = []
        self.nmt: list[bytes] = []
        self.sdo_requests: list[tuple[float, bytes]] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == 0x700 + LOGICAL:
            self.heartbeats.append((msg.timestamp, msg.data[0]))
        elif msg.arbitration_id == 0x000:
            self.nmt.append(bytes(msg.data))
        elif msg.arbitration_id == 0x600 + NODE_ID:
            self.sdo_requests.append((msg.timestamp, bytes(msg.data)))

    def longest_gap_s(self, since_s: float) -> float:
        stamps = [t for t, _ in self.heartbeats if t >= since_s]
        return max(b - a for a, b in zip(stamps, stamps[1:], strict=False))


def pair_configs() -> tuple[Any, Any]:
    base = make_config(
        [{"name": "enc", "node_id": NODE_ID, "profile": "posi_plus"}],
        master={"node_id": LOGICAL, "heartbeat_ms": HB_MS, "sync_period_ms": 0, "probe_at_start": False},
        modbus={"enabled": False},
        zenoh={"enabled": False},
        simulate={"nodes": []},
    )
    raw = base.model_dump(exclude_none=True)
    raw["nodes"][0]["sdo"] = [{"object": "0x1016:01", "value": CONSUMER_1016}]
    return member_configs(raw)


class Tpdo1(threading.Thread):
    """The encoder's TPDO1 (position, 6004h) every 50 ms, counting up, sent by the test."""

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(daemon=True)
        self.bus, self.stop, self.position = bus, threading.Event(), 1000

    def run(self) -> None:
        while not self.stop.wait(0.05):
            self.position += 1
            data = struct.pack("<I", self.position)
            self.bus.send(can.Message(arbitration_id=0x180 + NODE_ID, data=data, is_extended_id=False))


@asynccontextmanager
async def pair_with_localnode() -> AsyncIterator[
    tuple[Gateway, Gateway, Sent, Sent, canopen.LocalNode, LogicalHeartbeats]
]:
    cfg_a, cfg_b = pair_configs()
    net, node = local_node(EDS, NODE_ID, cfg_a.can.channel)
    bus = can.Bus(interface="virtual", channel=cfg_a.can.channel)
    heard = LogicalHeartbeats()
    notifier = can.Notifier(bus, [heard])
    a, b = gateway_of(cfg_a, simulate=False), gateway_of(cfg_b, simulate=False)
    sent_a, sent_b = Sent(a), Sent(b)
    hb, tpdo = Heartbeat(bus, node), Tpdo1(bus)
    try:
        await a.start()
        boot(node)
        hb.start()
        tpdo.start()
        await wait_until(lambda: node_operational(a, "enc"), 10, "A configures the LocalNode")
        await b.start()
        yield a, b, sent_a, sent_b, node, heard
    finally:
        for t in (hb, tpdo):
            t.stop.set()
            if t.is_alive():
                t.join()
        await b.stop()
        await a.stop()
        notifier.stop()
        bus.shutdown()
        net.disconnect()


def position_good(gw: Gateway) -> bool:
    node = gw.image.nodes["enc"]
    return node.quality(node.signals["position"]) is Quality.GOOD


async def test_the_localnodes_heartbeat_consumer_never_misses_the_logical_master_through_a_takeover() -> None:
    async with pair_with_localnode() as (a, b, sent_a, sent_b, node, heard):
        # A wrote the consumer into the device's own dictionary (an SDO server not ours)
        assert int.from_bytes(node.get_data(0x1016, 1), "little") == CONSUMER_1016
        assert node.nmt.state == "OPERATIONAL"
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        await wait_until(lambda: position_good(b), 5, "B serves the position good")
        await wait_until(lambda: len(heard.heartbeats) >= 3, 5, "the logical heartbeat on the bus")
        since_s = heard.heartbeats[0][0]
        nmt_before, sdo_before = len(heard.nmt), len(heard.sdo_requests)

        sent_a.silent = True  # A dies: not one more frame
        a.master.mastering = False
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        await wait_until(lambda: sent_b.count(0x700 + LOGICAL) >= 5, 5, "B's logical heartbeats")

        assert {s for _, s in heard.heartbeats} == {0x05}  # always OPERATIONAL
        gap_s = heard.longest_gap_s(since_s)
        # the consumer's rule (CiA 301 7.2.8.3.2.2): a gap longer than its time is a loss
        assert gap_s < CONSUMER_MS / 1000, f"logical heartbeat paused {gap_s * 1000:.0f} ms"
        assert gap_s > 2 * HB_MS / 1000  # the take-over was in the measured window
        # the device was adopted as it runs: no NMT command, no SDO request from anyone
        assert heard.nmt[nmt_before:] == []
        assert heard.sdo_requests[sdo_before:] == []
        assert not [c for c, _ in sent_b.frames if c in (0x000, 0x600 + NODE_ID)]
        assert node.nmt.state == "OPERATIONAL"
        assert int.from_bytes(node.get_data(0x1016, 1), "little") == CONSUMER_1016
        assert node_operational(b, "enc")
        assert position_good(b)


async def test_a_node_the_operator_put_pre_operational_is_adopted_so_by_the_new_active_one() -> None:
    """The operator's NMT state is part of what the standby follows: the LocalNode put
    PRE-OPERATIONAL through A (its NMT slave takes the command) stays so through the take-over;
    B sends it no NMT start, no SDO boot step, and reports it as A did."""
    async with pair_with_localnode() as (a, b, sent_a, sent_b, node, heard):
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        await wait_until(lambda: b.image.nodes["enc"].health.lifecycle == "operational", 5, "B heard it started")
        a.master.nmt("enc", "preop")  # the operator, through the active gateway
        preop = b.image.nodes["enc"].health
        await wait_until(lambda: preop.nmt_state.name == "PRE_OPERATIONAL", 5, "B hears it pre-operational")
        assert node.nmt.state == "PRE-OPERATIONAL"
        nmt_before, sdo_before = len(heard.nmt), len(heard.sdo_requests)

        sent_a.silent = True  # A dies
        a.master.mastering = False
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        # several of B's logical heartbeats, and as many of the node's, after the take-over
        n = sent_b.count(0x700 + LOGICAL)
        await wait_until(lambda: sent_b.count(0x700 + LOGICAL) >= n + 5, 5, "B masters the bus")

        assert heard.nmt[nmt_before:] == []  # no NMT start (nor anything else) to the device
        assert heard.sdo_requests[sdo_before:] == []  # no boot step, no probe
        assert node.nmt.state == "PRE-OPERATIONAL"
        rt = b.master.nodes["enc"]
        assert rt.lifecycle.state == "operational"  # adopted: managed by B, not reconfigured
        h = b.image.nodes["enc"].health
        assert h.alive and h.nmt_state.name == "PRE_OPERATIONAL" and h.loss_count == 0
        assert h.lifecycle == "operational"
        # A, its frames dropped (it still runs), met B's negotiation: its 75h drew no answer,
        # it stood down (a fresh joiner from then on)
        assert a.master.role != "active"
        b.master.nmt("enc", "start")  # the operator's next command goes through B
        await wait_until(lambda: node.nmt.state == "OPERATIONAL", 5, "started through B")
