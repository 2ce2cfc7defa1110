"""Commissioning commands: ``canopen-gateway lss ...`` against the simulated SGH10 LSS slave
(SGH10 manual 4.6) with the frames checked on the bus, the AP05 Auto-ID (AP05 manual 5.6.2)
against a raw-frame device, and ``canopen-gateway nmt``."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import can
import pytest
import yaml

from canopen_gateway.cli import main
from tests.helpers import unique_channel

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}


def config_file(tmp_path: Path, nodes: list[dict[str, Any]], simulate: Any = "all") -> Path:
    cfg = {
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 0},
        "nodes": nodes,
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": simulate},
    }
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return path


@contextmanager
def observer(path: Path) -> Iterator[list[can.Message]]:
    """Every frame on the config's bus while the block runs (drained at its end)."""
    channel = yaml.safe_load(path.read_text(encoding="utf-8"))["can"]["channel"]
    bus = can.Bus(interface="virtual", channel=channel)
    frames: list[can.Message] = []
    try:
        yield frames
        while (msg := bus.recv(timeout=0)) is not None:
            frames.append(msg)
    finally:
        bus.shutdown()


def lss_frames(frames: list[can.Message], cob: int) -> list[str]:
    return [bytes(m.data).hex(" ") for m in frames if m.arbitration_id == cob]


def test_lss_inquire_all_prints_the_lss_address_and_node_id(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config_file(tmp_path, [WIRE])
    with observer(path) as frames:
        assert main(["lss", "-c", str(path), "inquire"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [
        "vendor_id     0x00000195 (405)",  # SGH10 manual 4.6: vendor id 195h
        "product_code  0xFFFFFFFF (4294967295)",
        "revision      0xFFFFFFFF (4294967295)",
        "serial        0x00000001 (1)",
        "node_id       1",
    ]
    # SGH10 manual 4.6.1.1 / 4.6.3: switch global to configuration, 5Ah..5Eh, back to waiting
    assert lss_frames(frames, 0x7E5) == [
        "04 01 00 00 00 00 00 00",
        "5a 00 00 00 00 00 00 00",
        "5b 00 00 00 00 00 00 00",
        "5c 00 00 00 00 00 00 00",
        "5d 00 00 00 00 00 00 00",
        "5e 00 00 00 00 00 00 00",
        "04 00 00 00 00 00 00 00",
    ]
    assert lss_frames(frames, 0x7E4)[0] == "5a 95 01 00 00 00 00 00"


def test_lss_set_node_id_stores_and_activates_the_new_id(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config_file(tmp_path, [WIRE])
    with observer(path) as frames:
        assert main(["lss", "-c", str(path), "set-node-id", "5", "store", "activate"]) == 0
    out = capsys.readouterr().out
    assert "node id 5 configured" in out
    assert "node 1 reset: boot-up received from node 5" in out
    sent = lss_frames(frames, 0x7E5)
    assert "11 05 00 00 00 00 00 00" in sent  # 4.6.2.1 configure node id
    assert "17 00 00 00 00 00 00 00" in sent  # 4.6.2.4 store configuration
    assert "11 00 00 00 00 00 00 00" in lss_frames(frames, 0x7E4)  # 11h, error code 00h
    assert lss_frames(frames, 0x000)[-1] == "82 01"  # NMT reset communication to node 1
    assert lss_frames(frames, 0x705) == ["00"]  # boot-up with the new id


def test_lss_selective_switch_addresses_one_slave_by_its_lss_address(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config_file(tmp_path, [WIRE])
    args = ["lss", "-c", str(path), "inquire", "node_id"]
    assert main([*args, "address=0x195:0xFFFFFFFF:0xFFFFFFFF:1"]) == 0
    assert capsys.readouterr().out.strip() == "node_id       1"
    # serial 2 matches no slave: no 44h answer
    assert main([*args, "address=0x195:0xFFFFFFFF:0xFFFFFFFF:2", "timeout=0.2"]) == 1
    assert "switch state selective: no answer" in capsys.readouterr().err


def test_lss_set_bitrate_sends_the_table_index_and_refuses_rates_outside_the_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config_file(tmp_path, [WIRE])
    with observer(path) as frames:
        assert main(["lss", "-c", str(path), "set-bitrate", "250", "store"]) == 0
    # SGH10 manual 4.6.2.2: table selector 00h, index 3 = 250 kbit/s
    assert "13 00 03 00 00 00 00 00" in lss_frames(frames, 0x7E5)
    assert "13 00 00 00 00 00 00 00" in lss_frames(frames, 0x7E4)
    assert main(["lss", "-c", str(path), "set-bitrate", "333"]) == 2
    assert "not in the CiA 305 bit timing table" in capsys.readouterr().err


class FakeAutoIdDevice:
    """A raw-frame AP05 with the factory id 125 whose key is pressed at once (manual 5.6.2):
    it answers the 5F0Ah:02 write on 5FDh (or aborts) and boots with the new id."""

    def __init__(self, channel: str, abort_code: int | None = None):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.abort_code = abort_code
        self.requests: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> FakeAutoIdDevice:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()

    def _send(self, cob: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))

    def _run(self) -> None:
        answered = False
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.02)
            if msg is None or msg.arbitration_id != 0x67D or answered:
                continue
            data = bytes(msg.data)
            self.requests.append(data.hex(" "))
            if data[:4] != bytes([0x2F, 0x0A, 0x5F, 0x02]):
                continue
            answered = True
            if self.abort_code is not None:
                self._send(
                    0x5FD, bytes([0x80, 0x0A, 0x5F, 0x02]) + self.abort_code.to_bytes(4, "little")
                )
                continue
            self._send(0x5FD, bytes([0x60, 0x0A, 0x5F, 0x02, 0, 0, 0, 0]))
            self._send(0x700 + data[4], b"\x00")


def test_auto_id_writes_5f0ah_02_waits_for_the_key_press_and_the_boot_up(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config_file(tmp_path, [DISPLAY], simulate=[])
    channel = yaml.safe_load(path.read_text(encoding="utf-8"))["can"]["channel"]
    with FakeAutoIdDevice(channel) as device:
        assert main(["lss", "-c", str(path), "auto-id", "7", "timeout=3"]) == 0
    # AP05 manual table 32: 67Dh 2Fh 0Ah 5Fh 02h <new node id>
    assert device.requests[0] == "2f 0a 5f 02 07 00 00 00"
    out = capsys.readouterr().out
    assert "a device took node id 7" in out
    assert "boot-up received from node 7" in out
    assert "no device answers as node 125 any more" in out


def test_auto_id_refused_by_the_device_reports_the_abort_code(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = config_file(tmp_path, [DISPLAY], simulate=[])
    channel = yaml.safe_load(path.read_text(encoding="utf-8"))["can"]["channel"]
    with FakeAutoIdDevice(channel, abort_code=0x06090030):
        assert main(["lss", "-c", str(path), "auto-id", "7", "timeout=3"]) == 1
    assert "SDO abort 0x06090030" in capsys.readouterr().err


def test_nmt_command_goes_out_to_one_node_or_all(tmp_path: Path) -> None:
    path = config_file(tmp_path, [WIRE])
    with observer(path) as frames:
        assert main(["nmt", "-c", str(path), "stop", "wire"]) == 0
        assert main(["nmt", "-c", str(path), "reset-comm", "all"]) == 0
    nmt = lss_frames(frames, 0x000)
    assert nmt[-2:] == ["02 01", "82 00"]  # SGH10 manual 4.2.1.2 table 3


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["set-node-id", "200"], "out of range 1..127"),
        (["set-node-id"], "needs the new NODE_ID"),
        (["inquire", "colour"], "one of vendor_id"),
        (["switch-selective", "1", "2", "3"], "VENDOR PRODUCT REVISION SERIAL"),
        (["switch-global", "sleep"], "expected configuration or waiting"),
        (["store", "now"], "unexpected argument(s): now"),
        (["inquire", "timeout=soon"], "timeout='soon': expected a number"),
    ],
)
def test_lss_wrong_arguments_exit_2_with_what_is_expected(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    path = config_file(tmp_path, [WIRE], simulate=[])
    assert main(["lss", "-c", str(path), *args]) == 2
    assert message in capsys.readouterr().err
