"""``canopen-gateway lss`` command sequences against LSS slaves scripted here from the SGH10
manual 4.6 (raw frames on a virtual bus, not our simulator): each command is a new run of the
CLI, which continues from the state the previous one left the slaves in (Table 10), reports
several slaves answering one request, and refuses a bit rate the profile does not support
before sending anything."""

from __future__ import annotations

import struct
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import pytest
import yaml

from canopen_gateway.cli import main
from tests.helpers import unique_channel

VENDOR, PRODUCT, REVISION = 0x195, 0xFFFFFFFF, 0xFFFFFFFF  # SGH10 manual 4.6
SERIAL_A, SERIAL_B = 0x1111, 0x2222
ADDRESS_A = f"address={VENDOR:#x}:{PRODUCT:#x}:{REVISION:#x}:{SERIAL_A:#x}"


@dataclass
class Slave:
    """One LSS slave as manual 4.6 describes it (Table 10 decides what it ignores)."""

    serial: int
    node_id: int = 1
    state: str = "waiting"
    selective_step: int = 0  # 40h..43h matched so far, in order
    pending_node_id: int | None = None
    stored_node_id: int | None = None
    bit_timing_index: int | None = None

    @property
    def address(self) -> tuple[int, int, int, int]:
        return (VENDOR, PRODUCT, REVISION, self.serial)

    def on_request(self, d: bytes) -> bytes | None:
        cs = d[0]
        if cs == 0x04:  # 4.6.1.1 switch state global, no answer
            self.state = "configuration" if d[1] == 0x01 else "waiting"
            self.selective_step = 0
            return None
        if 0x40 <= cs <= 0x43:  # 4.6.1.2: only in waiting (Table 10)
            if self.state != "waiting":
                return None
            step = cs - 0x40
            value = struct.unpack_from("<I", d, 1)[0]
            if step == self.selective_step and value == self.address[step]:
                self.selective_step += 1
            else:
                self.selective_step = 0
            if self.selective_step == 4:
                self.selective_step = 0
                self.state = "configuration"
                return bytes([0x44]) + bytes(7)
            return None
        if self.state != "configuration":  # Table 10: everything else only in configuration
            return None
        if cs == 0x11:  # 4.6.2.1
            ok = 1 <= d[1] <= 0x7F
            if ok:
                self.pending_node_id = d[1]
            return bytes([0x11, 0 if ok else 1]) + bytes(6)
        if cs == 0x13:  # 4.6.2.2: table 00h, index 0..7
            ok = d[1] == 0 and d[2] in (0, 1, 2, 3, 4, 6, 7)
            if ok:
                self.bit_timing_index = d[2]
            return bytes([0x13, 0 if ok else 1]) + bytes(6)
        if cs == 0x17:  # 4.6.2.4
            self.stored_node_id = self.pending_node_id or self.node_id
            return bytes([0x17, 0]) + bytes(6)
        if 0x5A <= cs <= 0x5D:  # 4.6.3.1 - 4.6.3.4
            return bytes([cs]) + struct.pack("<I", self.address[cs - 0x5A]) + bytes(3)
        if cs == 0x5E:  # 4.6.3.5
            return bytes([cs, self.node_id]) + bytes(6)
        return None


@contextmanager
def lss_slaves(channel: str, slaves: list[Slave]) -> Iterator[list[Slave]]:
    """The slaves answer on 7E4h what they receive on 7E5h, from one thread."""
    bus = can.Bus(interface="virtual", channel=channel)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            msg = bus.recv(timeout=0.05)
            if msg is None or msg.arbitration_id != 0x7E5:
                continue
            for slave in slaves:
                answer = slave.on_request(bytes(msg.data))
                if answer is not None:
                    bus.send(can.Message(arbitration_id=0x7E4, data=answer, is_extended_id=False))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield slaves
    finally:
        stop.set()
        thread.join()
        bus.shutdown()


@contextmanager
def observer(channel: str) -> Iterator[list[can.Message]]:
    bus = can.Bus(interface="virtual", channel=channel)
    frames: list[can.Message] = []
    try:
        yield frames
        while (msg := bus.recv(timeout=0)) is not None:
            frames.append(msg)
    finally:
        bus.shutdown()


def sent(frames: list[can.Message]) -> list[str]:
    return [bytes(m.data).hex(" ") for m in frames if m.arbitration_id == 0x7E5]


@pytest.fixture
def setup(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, str]:
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    channel = unique_channel()
    cfg: dict[str, Any] = {
        "can": {"interface": "virtual", "channel": channel},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": []},
    }
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return path, channel


def lss(path: Path, *args: str) -> int:
    return main(["lss", "-c", str(path), *args])


def test_store_by_address_reaches_the_slave_a_kept_set_node_id_left_in_configuration(
    setup: tuple[Path, str],
) -> None:
    path, channel = setup
    with lss_slaves(channel, [Slave(SERIAL_A), Slave(SERIAL_B)]) as (a, b):
        assert lss(path, "set-node-id", "43", "keep", ADDRESS_A) == 0
        assert (a.state, a.pending_node_id, b.state) == ("configuration", 43, "waiting")
        with observer(channel) as frames:
            assert lss(path, "store", ADDRESS_A) == 0
        assert a.stored_node_id == 43 and b.stored_node_id is None
    # all to waiting first, then the selective switch the slave now obeys, store, waiting
    assert sent(frames) == [
        "04 00 00 00 00 00 00 00",
        "40 95 01 00 00 00 00 00",
        "41 ff ff ff ff 00 00 00",
        "42 ff ff ff ff 00 00 00",
        "43 11 11 00 00 00 00 00",
        "17 00 00 00 00 00 00 00",
        "04 00 00 00 00 00 00 00",
    ]


def test_commands_without_address_continue_with_the_slave_left_in_configuration(
    setup: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    path, channel = setup
    with lss_slaves(channel, [Slave(SERIAL_A), Slave(SERIAL_B)]) as (a, b), observer(
        channel
    ) as frames:
        assert lss(path, "switch-selective", f"{VENDOR}", f"{PRODUCT}", f"{REVISION}", f"{SERIAL_A}") == 0
        assert lss(path, "set-node-id", "7", "keep") == 0
        assert lss(path, "inquire", "serial", "keep") == 0
        assert f"serial        0x{SERIAL_A:08X}" in capsys.readouterr().out
        assert lss(path, "store") == 0
        assert (a.pending_node_id, a.stored_node_id) == (7, 7)
        assert (b.pending_node_id, b.stored_node_id) == (None, None)
    assert "04 01 00 00 00 00 00 00" not in sent(frames)  # never every slave at once
    assert sent(frames)[-1] == "04 00 00 00 00 00 00 00"  # the last command leaves all waiting


def test_a_slave_reset_since_the_previous_command_is_reported_and_forgotten(
    setup: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    path, channel = setup
    with lss_slaves(channel, [Slave(SERIAL_A)]) as (a,):
        assert lss(path, "switch-selective", *ADDRESS_A.split("=")[1].split(":")) == 0
        a.state = "waiting"  # power cycled: the slave starts in LSS waiting (manual 4.6)
        assert lss(path, "store", "timeout=0.2") == 1
        err = capsys.readouterr().err
        assert f"the slave 0x195:0xFFFFFFFF:0xFFFFFFFF:0x{SERIAL_A:X}" in err
        assert "give address=" in err
        assert lss(path, "store") == 0  # state forgotten: switch state global reaches it
        assert a.stored_node_id == 1


def test_global_inquire_answered_by_two_slaves_says_that_several_answered(
    setup: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    path, channel = setup
    with lss_slaves(channel, [Slave(SERIAL_A), Slave(SERIAL_B)]):
        assert lss(path, "inquire", "serial") == 1
    out, err = capsys.readouterr()
    assert f"2 slaves answered: 0x{SERIAL_A:08X} ({SERIAL_A}), 0x{SERIAL_B:08X} ({SERIAL_B})" in out
    assert "2 LSS slaves answered" in err and "address=" in err


def test_global_configure_answered_by_two_slaves_warns_that_each_took_it(
    setup: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    path, channel = setup
    with lss_slaves(channel, [Slave(SERIAL_A), Slave(SERIAL_B)]) as (a, b):
        assert lss(path, "set-node-id", "9") == 0
        assert a.pending_node_id == b.pending_node_id == 9
    assert "2 LSS slaves answered configure node id" in capsys.readouterr().err


def test_a_bit_rate_the_profile_does_not_support_is_refused_before_anything_is_sent(
    setup: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    path, channel = setup
    with lss_slaves(channel, [Slave(SERIAL_A)]) as (a,):
        with observer(channel) as frames:
            assert lss(path, "set-bitrate", "10", "store") == 2
        assert frames == []
        err = capsys.readouterr().err
        assert "10 kbit/s (table index 8) is not supported by profile sgh10 (nodes wire)" in err
        assert "1000, 800, 500, 250, 125, 50, 20 kbit/s" in err
        assert lss(path, "set-bitrate", "20", ADDRESS_A) == 0
        assert a.bit_timing_index == 7
