"""``scan`` and ``monitor`` on a python-can virtual bus, against our simulator, python canopen's
LocalNode (an SDO server that is not ours) and frames scripted from the manuals."""

from __future__ import annotations

import io
from collections.abc import Iterator
from contextlib import contextmanager

import can
import canopen
import pytest

from canopen_gateway.bus.scan import report, scan
from canopen_gateway.northbound.frames import FrameDecoder
from canopen_gateway.profiles import load_profile
from canopen_gateway.tools.monitor import monitor
from tests.helpers import gateway_of, make_config, simulated_bus, with_nodes

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 5, "profile": "ap05"}


def frame(cob_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


@contextmanager
def local_node(channel: str, node_id: int, profile: str) -> Iterator[canopen.LocalNode]:
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(node_id, str(load_profile(profile).eds_path))
    network.add_node(node)
    try:
        yield node
    finally:
        network.disconnect()


# --------------------------------------------------------------------------- frames in words


def test_frames_are_decoded_with_what_the_config_knows() -> None:
    d = FrameDecoder(*with_nodes(make_config([WIRE, DISPLAY])))
    # SGH10 manual 4.3: TPDO1 position (int32, 0.1 mm) and velocity
    tpdo = d.decode(0x181, (12345).to_bytes(4, "little") + (20).to_bytes(2, "little", signed=True))
    assert (tpdo.kind, tpdo.node, tpdo.service) == ("pdo", "wire", "TPDO1")
    assert tpdo.text.startswith("position=1234.5 mm velocity=")
    assert d.decode(0x000, b"\x02\x05").text == "stop to node id 5"
    assert d.decode(0x000, b"\x01\x00").text == "start to every node"
    assert d.decode(0x701, b"\x7f").text == "pre-operational"
    assert d.decode(0x701, b"\x00").text == "boot-up"
    emcy = d.decode(0x081, bytes([0x10, 0x81, 0x11, 0, 0, 0, 0, 0]))
    assert emcy.text.startswith("0x8110 (CAN overrun (objects lost)), error register 0x11")
    req = d.decode(0x601, bytes([0x40, 0x08, 0x10, 0, 0, 0, 0, 0]))
    assert (req.service, req.text) == ("SDO request", "upload 0x1008:00 (Manufacturer device name)")
    abort = d.decode(0x581, bytes([0x80, 0x00, 0x10, 0x00, 0x02, 0x00, 0x01, 0x06]))
    assert (
        abort.text
        == "abort 0x1000:00 (Device type): 0x06010002 Attempt to write a read only object"
    )
    answer = d.decode(0x581, bytes([0x43, 0x00, 0x10, 0x00, 0x96, 0x01, 0x0A, 0x00]))
    assert answer.text == "upload answer 0x1000:00 (Device type) = 655766 (0x000A0196)"
    other = d.decode(0x18A, bytes(2))
    assert (other.kind, other.node, other.node_id, other.service) == ("pdo", None, 10, "TPDO1")
    # CiA 305: Fast Scan (51h) is answered by identify slave (4Fh); identify non-configured
    # remote slave (4Ch) by 50h
    scan = d.decode(0x7E5, bytes([0x51, 0, 0, 0, 0, 0x80, 0, 0]))
    assert (scan.kind, scan.service, scan.text) == ("lss", "LSS request", "fast scan 00 00 00 00 80 00 00")
    assert d.decode(0x7E4, bytes([0x4F]) + bytes(7)).text.startswith("identify slave answer")
    assert d.decode(0x7E5, bytes([0x4C]) + bytes(7)).text.startswith("identify non-configured ")
    assert d.decode(0x7E4, bytes([0x50]) + bytes(7)).text.startswith("identify non-configured answer")


# --------------------------------------------------------------------------- monitor


def test_monitor_prints_decoded_frames_filtered_by_node_and_kind() -> None:
    cfg = make_config([WIRE, DISPLAY])
    channel = cfg.can.channel
    reader = can.Bus(interface="virtual", channel=channel)
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        for msg in [
            frame(0x701, b"\x05"),  # wire heartbeat: filtered out by kind
            frame(0x181, (100).to_bytes(4, "little") + bytes(2)),  # wire TPDO1
            frame(0x605, bytes([0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0])),  # display: other node
            frame(0x081, bytes([0x00, 0x50, 0x01, 0, 0, 0, 0, 0])),  # wire EMCY
            frame(0x581, bytes([0x80, 0x00, 0x60, 0x00, 0x00, 0x00, 0x02, 0x06])),  # wire abort
        ]:
            sender.send(msg)
        out = io.StringIO()
        n = monitor(reader, FrameDecoder(*with_nodes(cfg)), out, nodes={1}, kinds={"pdo", "emcy", "sdo"},
                    count=3, duration_s=30)  # fmt: skip
    finally:
        reader.shutdown()
        sender.shutdown()
    assert n == 3
    lines = [line.split(None, 1)[1] for line in out.getvalue().splitlines()]  # without the time
    assert lines[0] == "181  wire         TPDO1         position=10 mm velocity=0 mm/s"
    assert lines[1].startswith("081  wire         EMCY          0x5000 (")
    assert lines[2] == (
        "581  wire         SDO answer    abort 0x6000:00 (Operating parameters): "
        "0x06020000 Object does not exist in the object dictionary"
    )


# --------------------------------------------------------------------------- scan


def test_scan_finds_our_simulator_a_local_node_and_a_scripted_heartbeat() -> None:
    """wire (id 1, our simulator) and a POSI+ (id 7, python canopen's LocalNode) answer SDO;
    id 9 only sends heartbeats; the configured display (id 5) is silent."""
    cfg = make_config([WIRE, DISPLAY])
    channel = cfg.can.channel
    sim = simulated_bus(cfg, ["wire"])
    sim.start()
    talker = can.Bus(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        with local_node(channel, 7, "posi_plus"):

            def script() -> None:  # frames sent once the scan listens
                talker.send(frame(0x709, b"\x05"))
                talker.send(frame(0x189, bytes(4)))

            found = scan(bus, listen_s=0.5, active=True, sdo_timeout_s=0.3,
                         node_ids=range(1, 16), on_listening=script)  # fmt: skip
    finally:
        bus.shutdown()
        talker.shutdown()
        sim.stop()
    assert sorted(found) == [1, 7, 9]
    assert found[1].name == "SGH10" and found[1].device_type == 0x000A0196
    assert found[1].vendor == 0x195
    assert found[7].name == "POSI+" and found[7].vendor == 0x184
    assert found[9].state == "operational" and found[9].device_type is None
    lines = report(found, cfg, active=True)
    text = "\n".join(lines)
    row = {int(line.split()[0]): line for line in lines[1:] if line.split()[0].isdigit()}
    assert row[1].endswith("profile sgh10; config node wire (sgh10)")
    assert row[7].endswith("profile posi_plus; not in the config")
    assert row[9].split()[1] == "operational" and row[9].endswith("not in the config")
    assert row[5] == "  5  not found: config node display (ap05)"
    assert (
        "configured but not found: display; found but not configured: node id 7, 9 "
        "(a wrong node_id?)"
    ) in text


async def test_the_console_scans_the_bus_on_the_gateways_own_connection(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``POST /api/commission/scan`` (web.writes and the token) on the gateway's own connection
    (no second ``can.Bus``: it works on interfaces that allow one connection) finds its
    simulated wire, read by the master's SDO client, and a LocalNode the config does not know,
    probed by the scan's own; another node with the gateway's node id is a conflict."""
    import asyncio
    import json
    import urllib.request

    from tests.helpers import free_port, node_operational, wait_until

    token = "scan-test-token-12"
    cfg = make_config([WIRE], health={"port": free_port()}, web={"writes": True, "token": token})
    gw = gateway_of(cfg)
    await gw.start()
    spy = can.Bus(interface="virtual", channel=cfg.can.channel)  # every frame on the bus
    talker = can.Bus(interface="virtual", channel=cfg.can.channel)
    try:
        await wait_until(lambda: node_operational(gw, "wire"), what="wire operational")
        while spy.recv(0) is not None:  # what came before the scan
            pass

        def no_second_connection(*args: object, **kwargs: object) -> None:
            raise can.CanInitializationError("this interface allows one connection per channel")

        with local_node(cfg.can.channel, 7, "posi_plus"):
            monkeypatch.setattr(can, "Bus", no_second_connection)

            def post() -> dict:
                req = urllib.request.Request(
                    f"http://127.0.0.1:{gw.health.port}/api/commission/scan", data=b"{}",
                    method="POST", headers={"Authorization": f"Bearer {token}"},
                )  # fmt: skip
                with urllib.request.urlopen(req, timeout=30) as r:
                    return json.loads(r.read())

            async def scan_while_talking() -> dict:
                task = asyncio.create_task(asyncio.to_thread(post))
                await wait_until(lambda: gw.driver.frame_taps != (), what="the scan listens")
                talker.send(frame(0x700 + 127, b"\x7f"))  # a heartbeat with the gateway's id
                return await task

            doc = await scan_while_talking()
            monkeypatch.undo()
        assert gw.driver.frame_taps == ()  # the scan's tap is gone
        sent = []
        while (msg := spy.recv(0)) is not None:
            sent.append(msg)
    finally:
        talker.shutdown()
        spy.shutdown()
        await gw.stop()
    assert doc["ok"] is True
    assert sorted(n["node_id"] for n in doc["nodes"]) == [1, 7, 127]
    wire = next(n for n in doc["nodes"] if n["node_id"] == 1)
    assert (wire["name"], wire["vendor"], wire["device_type"]) == ("SGH10", 0x195, 0x000A0196)
    rows = {line.split()[0]: line for line in doc["report"][1:]}
    assert rows["1"].split()[1] == "operational"
    assert rows["1"].endswith("profile sgh10; config node wire (sgh10)")
    assert rows["7"].endswith("profile posi_plus; not in the config")
    assert rows["127"].endswith(
        "not the gateway but another node with its master.node_id 127: a node id conflict"
    )
    # id 1 is the master's: its 1000h upload request (repeated only by the master's own SDO
    # retry when a loaded machine answers late), none by the scan
    uploads_1000 = [m for m in sent if m.arbitration_id == 0x601 and bytes(m.data[:4]) == b"\x40\x00\x10\x00"]
    assert 1 <= len(uploads_1000) <= 1 + gw.cfg.master.sdo_retries
    # every other id got the scan's 1000h probe, once, on the gateway's connection
    probed = {m.arbitration_id - 0x600 for m in sent
              if 0x600 < m.arbitration_id < 0x680 and bytes(m.data[:4]) == b"\x40\x00\x10\x00"}  # fmt: skip
    assert probed == set(range(1, 128))
