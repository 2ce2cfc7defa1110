"""Bus traces: ``monitor --record FILE`` writes every frame through python-can's writer of
FILE's format (.asc, .blf, .trc, .log, .csv) and ``decode FILE`` prints one line per frame of
any trace python-can's LogReader reads, in CANopen words: the node and what it is (heartbeat
and the state, the TPDO's signal names with values, SDO, EMCY with the manual's text, NMT).
The frames are scripted from CiA 301 and the SGH10 manual, not made by our simulator."""

from __future__ import annotations

import io
import threading
from pathlib import Path

import can
import pytest
import yaml

from canopen_gateway.cli import main
from tests.helpers import frame, unique_channel

#: a heartbeat, an NMT start, a TPDO1 (position 12345 = 1234.5 mm, velocity 7 mm/s, SGH10
#: manual 4.3), an SDO upload of 1008h and its answer, an EMCY 8120h (SGH10 manual 4.5.1)
SCRIPT = [
    frame(0x701, "05"),
    frame(0x000, "01 01"),
    frame(0x181, "39 30 00 00 07 00"),
    frame(0x601, "40 08 10 00 00 00 00 00"),
    frame(0x581, "43 08 10 00 53 47 48 31"),
    frame(0x081, "20 81 11 00 00 00 00 00"),
]
EXPECTED = [
    ("wire", "heartbeat", "operational"),
    ("wire", "NMT", "start"),
    ("wire", "TPDO1", "position=1234.5 mm"),
    ("wire", "SDO request", "0x1008:00"),
    ("wire", "SDO answer", "0x1008:00"),
    ("wire", "EMCY", "error passive"),
]


@pytest.fixture
def config(tmp_path: Path) -> Path:
    raw = {"can": {"interface": "virtual", "channel": unique_channel()},
           "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
           "simulate": {"nodes": []}, "health": {"port": 0}}  # fmt: skip
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


def check_lines(text: str, expected: list[tuple[str, str, str]]) -> None:
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == len(expected), text
    for line, words in zip(lines, expected, strict=True):
        for w in words:
            assert w.lower() in line.lower(), (w, line)


def run_monitor_while_sending(channel: str, run: object) -> None:
    """``run()`` (a monitor on ``channel`` that stops after the script's lines) in a thread,
    while a device sends the script until the monitor has it (bounded)."""
    t = threading.Thread(target=run)  # type: ignore[arg-type]
    with can.Bus(interface="virtual", channel=channel) as device:
        t.start()
        for _ in range(600):
            for msg in SCRIPT:
                device.send(msg)
            t.join(timeout=0.05)
            if not t.is_alive():
                break
    t.join(timeout=30)
    assert not t.is_alive()


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".trc", ".log", ".csv"])
def test_a_recording_in_each_format_decodes_back_to_the_frames(
    config: Path, tmp_path: Path, suffix: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from canopen_gateway.bus.trace import trace_writer
    from canopen_gateway.northbound.frames import FrameDecoder
    from canopen_gateway.tools.monitor import monitor
    from tests.helpers import load_checked_config, with_nodes

    cfg, nodes = with_nodes(load_checked_config(config))
    trace = tmp_path / f"trace{suffix}"
    record = trace_writer(str(trace))
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    decoder = FrameDecoder(cfg, nodes)
    sink = io.StringIO()
    run_monitor_while_sending(
        cfg.can.channel, lambda: monitor(bus, decoder, sink, count=len(SCRIPT), record=record)
    )
    bus.shutdown()
    record.stop()
    assert main(["decode", "-c", str(config), str(trace)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(list(can.LogReader(str(trace)))) >= len(SCRIPT)
    first = next(i for i, line in enumerate(lines) if " 701 " in line)
    check_lines("\n".join(lines[first : first + len(SCRIPT)]), EXPECTED)


def test_monitor_command_records_with_record_and_decode_reads_it(
    config: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "bus.blf"
    channel = yaml.safe_load(config.read_text(encoding="utf-8"))["can"]["channel"]
    result: list[int] = []
    args = ["monitor", "-c", str(config), "--count", str(len(SCRIPT)), "--record", str(trace)]
    run_monitor_while_sending(channel, lambda: result.append(main(args)))
    assert result == [0]
    printed = capsys.readouterr().out
    assert main(["decode", "-c", str(config), str(trace)]) == 0
    decoded = capsys.readouterr().out
    assert len(decoded.splitlines()) == len(list(can.LogReader(str(trace))))
    assert "position=1234.5 mm" in printed and "position=1234.5 mm" in decoded


def test_decode_reads_a_trace_python_can_wrote_one_line_per_frame(
    config: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "t.asc"
    writer = can.Logger(str(trace))
    extra = [can.Message(arbitration_id=0x18FEF100, data=b"\1\2", is_extended_id=True),
             can.Message(is_error_frame=True, arbitration_id=0x4, data=bytes(8), is_extended_id=False)]  # fmt: skip
    for i, msg in enumerate([*SCRIPT, *extra]):
        msg.timestamp = 100.0 + i * 0.01
        writer.on_message_received(msg)
    writer.stop()
    assert main(["decode", "-c", str(config), str(trace)]) == 0
    out = capsys.readouterr().out
    check_lines(out, [*EXPECTED, ("-", "29-bit", "18FEF100"), ("-", "error frame", "")])
    assert out.splitlines()[0].split()[0] == "0.000" and out.splitlines()[1].split()[0] == "0.010"


def test_record_refuses_a_format_python_can_does_not_write(config: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["monitor", "-c", str(config), "--count", "1", "--record", "trace.pcap"]) == 2
    assert ".asc, .blf, .trc, .log, .csv" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".asc", ".trc"])
def test_a_remote_frame_is_recorded_where_the_format_holds_it_and_counted_where_not(
    tmp_path: Path, suffix: str
) -> None:
    """Node guarding's request (an RTR on 701h): kept in .asc; a .trc cannot hold it
    (python-can's TRC writer), so it is left out, counted and said, never logged per frame."""
    from canopen_gateway.bus.trace import trace_writer

    trace = tmp_path / f"rtr{suffix}"
    writer = trace_writer(str(trace))
    for i, msg in enumerate([can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False),
                             can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False)]):  # fmt: skip
        msg.timestamp = 100.0 + i * 0.01
        writer.on_message_received(msg)
    writer.stop()
    read = list(can.LogReader(str(trace)))
    if suffix == ".asc":
        assert [m.is_remote_frame for m in read] == [True, False] and writer.note() is None
    else:
        assert [m.is_remote_frame for m in read] == [False] and writer.left_out == 1
        assert (writer.note() or "").startswith("1 remote frame(s) (RTR, e.g. node guarding) not recorded")
