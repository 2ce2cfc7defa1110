"""SimRunner on a python-can virtual bus, checked with real clients (python-can, canopen)."""

from __future__ import annotations

import time
import uuid

import can
import canopen
import pytest

from canopen_gateway.profiles import load_profile
from canopen_gateway.sim.runner import SimRunner, build_sim_nodes


def _recv_until(bus: can.BusABC, cob_id: int, timeout_s: float = 2.0) -> can.Message:
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        msg = bus.recv(timeout=left)
        if msg is not None and msg.arbitration_id == cob_id:
            return msg
    raise AssertionError(f"no frame 0x{cob_id:03X} within {timeout_s} s")


@pytest.fixture
def channel() -> str:
    return f"sim-runner-{uuid.uuid4().hex}"


def test_runner_boots_node_answers_sdo_and_streams_tpdos(channel: str) -> None:
    profile = load_profile("sgh10")
    nodes = build_sim_nodes([(profile, 3, {"motion": {"kind": "ramp", "speed": 5000}})])
    sim_bus = can.Bus(interface="virtual", channel=channel)
    client = can.Bus(interface="virtual", channel=channel)
    network = canopen.Network()
    runner = SimRunner(sim_bus, nodes)
    try:
        runner.start()
        assert _recv_until(client, 0x703).data == b"\x00"  # boot-up

        network.connect(interface="virtual", channel=channel)
        remote = network.add_node(3, profile.od)
        remote.sdo.RESPONSE_TIMEOUT = 1.0
        # segmented upload; the last segment's command byte 03h (manual 4.4.1.4) declares 6
        # valid bytes, so a DS-301 client receives a trailing NUL that string decoding drops
        assert remote.sdo.upload(0x1008, 0) == b"SGH10\x00"
        assert remote.sdo[0x1008].raw == "SGH10"
        remote.sdo.download(0x1800, 5, (20).to_bytes(2, "little"))  # event timer 20 ms
        assert int.from_bytes(remote.sdo.upload(0x6200, 0), "little") == 20

        client.send(can.Message(arbitration_id=0, data=b"\x01\x03", is_extended_id=False))
        first = _recv_until(client, 0x183)
        second = _recv_until(client, 0x183)
        assert len(first.data) == 6
        assert first.data[:4] != second.data[:4]  # the position moves
    finally:
        runner.stop(timeout_s=1.0)
        assert not runner.running
        assert runner.error is None
        network.disconnect()
        client.shutdown()
        sim_bus.shutdown()


def test_call_injects_a_fault_from_another_thread(channel: str) -> None:
    nodes = build_sim_nodes([(load_profile("sgh10"), 4, None)])
    sim_bus = can.Bus(interface="virtual", channel=channel)
    client = can.Bus(interface="virtual", channel=channel)
    try:
        with SimRunner(sim_bus, nodes) as runner:
            _recv_until(client, 0x704)
            runner.call(lambda now: nodes[0].raise_emcy(0xFF05, 0x80, now=now))
            emcy = _recv_until(client, 0x084)
            assert bytes(emcy.data) == bytes.fromhex("05 FF 81 00 00 00 00 00")
            thread = runner._thread
        # stop() joined the thread: it has ended (a join that gave up would leave it alive)
        assert thread is not None and not thread.is_alive()
        assert not runner.running and runner.error is None
    finally:
        client.shutdown()
        sim_bus.shutdown()


def test_node_listens_to_its_cob_ids_and_says_when_they_change() -> None:
    """The runner hands a node only the standard frames of ``listening()``; it must follow
    COB-ID changes (DS-301: bit 31 first) and a node not yet powered takes every frame."""
    (node,) = build_sim_nodes([(load_profile("sgh10"), 3, None)])
    assert node.listening() is None  # not powered yet
    changes: list[int] = []
    node.on_listening_changed = lambda: changes.append(1)
    node.power_on(0.0)
    cobs = node.listening()
    assert cobs is not None and changes
    # NMT, guarding RTR, SYNC, SDO request, TPDO RTR, LSS (SGH10 manual 4.6)
    assert {0x000, 0x703, 0x080, 0x603, 0x183, 0x283, 0x7E5} <= cobs
    assert not {0x604, 0x583, 0x704, 0x184} & cobs
    changes.clear()
    node.set(0x1800, 1, 0x80000183)
    node.set(0x1800, 1, 0x00000190)
    assert changes
    cobs = node.listening()
    assert cobs is not None and 0x190 in cobs and 0x183 not in cobs


def test_runner_dispatch_answers_only_the_addressed_node_and_follows_a_cob_change(
    channel: str,
) -> None:
    profile = load_profile("sgh10")
    nodes = build_sim_nodes([(profile, i, None) for i in (3, 4, 5)])
    sim_bus = can.Bus(interface="virtual", channel=channel)
    client = can.Bus(interface="virtual", channel=channel)
    runner = SimRunner(sim_bus, nodes)
    try:
        runner.start()
        for i in (3, 4, 5):
            _recv_until(client, 0x700 + i)  # boot-ups
        upload_1000 = bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0])
        client.send(can.Message(arbitration_id=0x604, data=upload_1000, is_extended_id=False))
        answers = []
        while (msg := client.recv(timeout=2.0)) is not None:
            answers.append(msg.arbitration_id)
            if msg.arbitration_id == 0x584:
                break
        assert 0x584 in answers and not {0x583, 0x585} & set(answers)
        # TPDO1 of node 5 to 0x1F5 (bit 31 first), then an RTR on it in OPERATIONAL
        for value in (0x80000185, 0x000001F5):
            req = bytes([0x23, 0x00, 0x18, 0x01]) + value.to_bytes(4, "little")
            client.send(can.Message(arbitration_id=0x605, data=req, is_extended_id=False))
            assert _recv_until(client, 0x585).data[0] == 0x60
        client.send(can.Message(arbitration_id=0, data=b"\x01\x05", is_extended_id=False))
        client.send(
            can.Message(arbitration_id=0x1F5, is_remote_frame=True, dlc=6, is_extended_id=False)
        )
        assert len(_recv_until(client, 0x1F5).data) == 6
    finally:
        runner.stop(timeout_s=1.0)
        assert runner.error is None
        client.shutdown()
        sim_bus.shutdown()
