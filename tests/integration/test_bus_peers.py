"""Others on the bus, as the gateway reports them: another master (NMT commands we did not send,
a heartbeat on our own COB-ID) is one warning, a metric and a field of /healthz and the web
console's overview; SDO requests of another client (python canopen's SDO client, as a
commissioning tool would send them) are an info line once per node and period, never a
warning; a node that does not appear names the node ids that talk instead."""

from __future__ import annotations

import asyncio
import json
import logging
import urllib.request

import can
import canopen
import pytest

from canopen_gateway.bus.bus_peers import BusPeers
from canopen_gateway.canopen.connection_set import describe_cob_id
from tests.helpers import free_port, master_running, node_operational, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


async def http_json(url: str) -> dict:
    def fetch() -> dict:
        with urllib.request.urlopen(url, timeout=5) as r:
            return json.loads(r.read())

    return await asyncio.to_thread(fetch)


async def http_text(url: str) -> str:
    def fetch() -> str:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.read().decode()

    return await asyncio.to_thread(fetch)


def frame(cob_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


def records(caplog: pytest.LogCaptureFixture, text: str, level: int | None = None) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if text in r.getMessage() and (level is None or r.levelno == level)
    ]


async def test_another_master_is_one_warning_each_a_metric_healthz_and_console(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    port = free_port()
    async with master_running([WIRE], health={"port": port}) as gw:
        await wait_until(lambda: node_operational(gw, "wire"), what="wire operational")
        other = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            for _ in range(3):
                other.send(frame(0x000, bytes([0x02, 0x01])))  # NMT stop to node 1
                other.send(frame(0x77F, b"\x7f"))  # a heartbeat on our own COB-ID
            await wait_until(
                lambda: (
                    gw.master.peers.other_master.get("nmt")
                    and gw.master.peers.other_master["nmt"].count == 3
                    and gw.master.peers.other_master.get("heartbeat")
                    and gw.master.peers.other_master["heartbeat"].count == 3
                ),
                what="the other master's frames",
            )
        finally:
            other.shutdown()
        nmt = records(caplog, "another master on the bus", logging.WARNING)
        assert nmt == [
            "another master on the bus: NMT stop to node id 1, which this gateway did not send; "
            "two masters fight over the nodes (states, guarding): keep one"
        ]
        hb = records(caplog, "uses this gateway's node id 127", logging.WARNING)
        assert len(hb) == 1
        assert "heartbeat 0x77F (pre-operational) from another device" in hb[0]
        assert "change master.node_id of one of them" in hb[0]

        health = await http_json(f"http://127.0.0.1:{port}/healthz")
        seen = health["bus_peers"]["other_master"]
        assert seen["nmt"]["count"] == 3 and seen["nmt"]["detail"] == "NMT stop to node id 1"
        assert seen["heartbeat"]["count"] == 3
        overview = await http_json(f"http://127.0.0.1:{port}/api/overview")
        assert overview["overview"]["peers"]["other_master"]["nmt"]["count"] == 3
        metrics = await http_text(f"http://127.0.0.1:{port}/metrics")
        assert 'canopen_gateway_other_master_frames_total{kind="nmt"} 3.0' in metrics
        assert 'canopen_gateway_other_master_frames_total{kind="heartbeat"} 3.0' in metrics


async def test_our_own_nmt_and_heartbeat_are_not_another_master() -> None:
    async with master_running([WIRE]) as gw:
        await wait_until(lambda: node_operational(gw, "wire"), what="wire operational")
        await gw.commands.nmt("wire", "start")  # an NMT command of our own
        watcher = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            # our heartbeat went out at least once more: the bus saw what we send
            msg = await asyncio.to_thread(watcher.recv, 5.0)
            while msg is not None and msg.arbitration_id != 0x77F:
                msg = await asyncio.to_thread(watcher.recv, 5.0)
            assert msg is not None
        finally:
            watcher.shutdown()
        assert gw.master.peers.other_master == {}


async def test_sdo_client_of_another_tool_is_info_once_never_a_warning(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    async with master_running([WIRE]) as gw:
        await wait_until(lambda: node_operational(gw, "wire"), what="wire operational")
        network = canopen.Network()
        network.connect(interface="virtual", channel=gw.cfg.can.channel)
        try:
            tool = canopen.RemoteNode(1, canopen.ObjectDictionary())
            network.add_node(tool)
            for _ in range(3):  # a commissioning tool reads the device type
                raw = await asyncio.to_thread(tool.sdo.upload, 0x1000, 0)
                assert int.from_bytes(raw, "little") & 0xFFFF == 406  # DS-406 encoder
        finally:
            network.disconnect()
        await wait_until(
            lambda: (
                gw.master.peers.sdo_clients.get("wire")
                and gw.master.peers.sdo_clients["wire"].count >= 3
            ),
            what="the other client's requests",
        )
    assert not [
        r for r in caplog.records if r.levelno >= logging.WARNING and "0x601" in r.getMessage()
    ]
    info = records(caplog, "another SDO client talks to node wire", logging.INFO)
    assert info == [
        "another SDO client talks to node wire (id 1): upload of 0x1000:00 "
        "(a commissioning tool? normal on a shared bus)"
    ]


async def test_node_that_does_not_appear_names_the_ids_that_talk(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The device is node 1; the config says 5. The boot timeout names node id 1."""
    caplog.set_level(logging.INFO, logger="gateway")
    wrong = {**WIRE, "node_id": 5}
    async with master_running(
        [wrong], simulate={"nodes": []}, master={"boot_timeout_s": 3, "heartbeat_ms": 0}
    ) as gw:
        device = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            device.send(frame(0x701, b"\x05"))  # heartbeat of node 1
            device.send(frame(0x181, bytes(8)))  # its TPDO1
            lines = await wait_until(
                lambda: records(caplog, "did not appear"), timeout_s=15, what="boot timeout"
            )
        finally:
            device.shutdown()
    assert lines == [
        "node wire (id 5): node did not appear (no boot-up) within 3 s; node ids talking on "
        "this bus but not configured: 1 (TPDO1 0x181, heartbeat 0x701) "
        "(a wrong node_id in the config?)"
    ]
    assert records(caplog, "frame with unexpected COB-ID 0x701 (heartbeat of node id 1) ignored")


async def test_node_that_does_not_appear_beside_nodes_that_talk_says_the_bus_works(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A configured node that is gone (unplugged) while the other configured nodes talk: no id
    outside the config talks, and the line says so, not that no other id talks."""
    caplog.set_level(logging.INFO, logger="gateway")
    gone = {"name": "display", "node_id": 125, "profile": "ap05"}
    async with master_running(
        [WIRE, gone], simulate={"nodes": ["wire"]}, master={"boot_timeout_s": 3, "heartbeat_ms": 0}
    ):
        lines = await wait_until(
            lambda: records(caplog, "did not appear"), timeout_s=15, what="boot timeout"
        )
    assert lines[0].endswith(
        "; no node id outside the config talks on this bus (configured nodes heard: wire; "
        "is this device powered and connected?)"
    ), lines
    assert "no other node id talks" not in lines[0]


def test_with_the_echo_on_our_own_frames_are_matched_and_others_still_seen() -> None:
    peers = BusPeers(127, {1}, echo=True)
    peers.sent(0x000, b"\x01\x01", now=10.0)
    assert peers.on_nmt(b"\x01\x01", wall=0.0, now=10.001) is None  # the echo of our own
    assert peers.on_nmt(b"\x01\x01", wall=0.0, now=10.002) is not None  # a second one: not ours
    peers.sent(0x77F, b"\x05", now=10.0)
    assert peers.on_own_heartbeat(b"\x05", wall=0.0, now=10.0) is None
    assert peers.on_own_heartbeat(b"\x00", wall=0.0, now=10.0) is not None  # a boot-up: not ours
    peers.sent(0x000, b"\x02\x00", now=10.0)
    assert peers.on_nmt(b"\x02\x00", wall=0.0, now=12.0) is not None  # too late for an echo


def test_cob_ids_are_described_by_the_predefined_connection_set() -> None:
    assert describe_cob_id(0x181) == "TPDO1 of node id 1"
    assert describe_cob_id(0x4FF) == "TPDO4 of node id 127"
    assert describe_cob_id(0x605) == "SDO request of node id 5"
    assert describe_cob_id(0x000) == "NMT"
    assert describe_cob_id(0x7E5) == "LSS"
    assert describe_cob_id(0x720) == "heartbeat of node id 32"
    assert describe_cob_id(0x7A0) == "COB-ID 0x7A0"
    assert describe_cob_id(0x050) == "COB-ID 0x050"


async def test_with_the_echo_on_a_second_gateway_with_our_node_id_and_state_is_seen() -> None:
    """``can.receive_own_messages``: the gateway's own heartbeats (operational, 05h) come back
    from the bus and are taken as its own, none left waiting; another device sending the very
    same heartbeat on 77Fh is another master all the same."""
    async with master_running(
        [WIRE], can={"receive_own_messages": True}, master={"heartbeat_ms": 20}
    ) as gw:
        peers = gw.master.peers
        assert peers.echo
        spy = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            seen = [0]

            def heartbeats_seen() -> bool:
                while (msg := spy.recv(0)) is not None:
                    seen[0] += msg.arbitration_id == 0x77F
                return seen[0] >= 30

            await wait_until(heartbeats_seen, what="30 heartbeats of the gateway")
            assert "heartbeat" not in peers.other_master
            assert peers.echoes_pending <= 2  # each echo took its frame
            spy.send(frame(0x77F, b"\x05"))  # a second gateway with node id 127, operational
            await wait_until(
                lambda: "heartbeat" in peers.other_master, what="the second gateway seen"
            )
            assert peers.other_master["heartbeat"].count == 1
        finally:
            spy.shutdown()
