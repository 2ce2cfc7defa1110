"""A CAN bus that cannot be opened, for every command that opens it: one line on stderr naming
``can.interface`` / ``can.channel``, the reason the OS or the backend gave and a hint, exit 2,
no traceback (``canopen_gateway.tools.bus_open``).

Two buses that cannot open on this machine: SocketCAN ``can9`` (this kernel has no AF_CAN,
errno 97; a kernel with SocketCAN and no such interface says errno 19) and a ``remote`` CAN
server at a port nobody listens on (connection refused). Every command runs through the
program's own ``main``; one runs as its own process as a user starts it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from canopen_gateway.entry import main as entry_main
from tests.helpers import free_port

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}

BUSES = {
    "socketcan": ({"interface": "socketcan", "channel": "can9"}, "can.channel: can9", "errno"),
    "remote": (
        {"interface": "remote", "channel": "ws://127.0.0.1:{port}/"},
        "can.channel: ws://127.0.0.1:",
        "nothing listens there",
    ),
    # refused at once (python-can's own socketcand bus would retry for 10 s without a pause)
    "socketcand": (
        {"interface": "socketcand", "host": "127.0.0.1", "port": "{port}", "channel": "can0"},
        "can.channel: can0, can.host: 127.0.0.1, can.port: ",
        "nothing listens there",
    ),
}

COMMANDS = {
    "run": ["run"],
    "simulate": ["simulate"],
    "scan": ["scan", "--active"],
    "monitor": ["monitor", "--count", "1"],
    "sdo": ["sdo", "read", "wire", "0x1008:00"],
    "nmt": ["nmt", "stop", "all"],
    "lss": ["lss", "inquire"],
}


def write_config(path: Path, can: dict[str, Any]) -> Path:
    can = {k: v.format(port=free_port()) if isinstance(v, str) else v for k, v in can.items()}
    raw = {
        "gateway": {"name": "nobus"},
        "can": can,
        "master": {"heartbeat_ms": 0},
        "nodes": [WIRE],
        "modbus": {"port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
        "health": {"port": free_port()},
        "simulate": {"nodes": "all"},
    }
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


@pytest.mark.parametrize("bus", sorted(BUSES))
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_bus_that_cannot_open_is_one_line_naming_the_setting_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, bus: str
) -> None:
    can, channel, reason = BUSES[bus]
    cfg = write_config(tmp_path / "plant.yaml", can)
    argv = [*COMMANDS[command][:1], "-c", str(cfg), *COMMANDS[command][1:]]
    code = entry_main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.splitlines()
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"error: {cfg}: can.interface: {can['interface']}, {channel}"), line
    assert "the CAN bus cannot be opened" in line and reason in line, line


def test_the_socketcan_line_says_why_and_what_to_check(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = write_config(tmp_path / "plant.yaml", BUSES["socketcan"][0])
    assert entry_main(["scan", "-c", str(cfg), "--active"]) == 2
    line = capsys.readouterr().err.strip()
    # no AF_CAN in this kernel (97): the module; a kernel with SocketCAN: no such device (19)
    assert ("(errno 97); this kernel has no SocketCAN" in line and "modprobe can_raw" in line) or (
        "(errno 19); no such device" in line
    ), line


def test_scan_as_its_own_process_prints_no_traceback(tmp_path: Path) -> None:
    cfg = write_config(tmp_path / "plant.yaml", BUSES["remote"][0])
    proc = subprocess.run(
        [sys.executable, "-m", "canopen_gateway", "scan", "-c", str(cfg), "--active"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.splitlines()) == 1, proc.stderr
    assert "can.interface: remote" in proc.stderr and "Connection refused" in proc.stderr


def test_fault_opens_no_bus_and_says_in_one_line_that_no_gateway_answers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``fault`` goes through a running gateway's web API, never the bus: with a bus that
    cannot open and no gateway, it names the address nobody answers at (exit 1)."""
    cfg = write_config(tmp_path / "plant.yaml", BUSES["socketcan"][0])
    code = entry_main(["fault", "-c", str(cfg), "wire", "unplug"])
    err = capsys.readouterr().err
    assert code == 1, err
    assert len(err.splitlines()) == 1 and "no gateway answers at http://127.0.0.1:" in err, err


def test_run_opens_its_bus_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``run`` opens the configured bus once, by the gateway itself (a CAN server that takes one
    client, as a socketcand stub may, is not used up by a trial open before the start)."""
    import can

    import canopen_gateway.cli.serve as serve
    from tests.helpers import unique_channel

    opened: list[dict[str, Any]] = []
    real_bus = can.Bus

    def counting_bus(*args: Any, **kwargs: Any) -> Any:
        opened.append(kwargs)
        return real_bus(*args, **kwargs)

    async def start_and_stop(starter: Any, stopper: Any, ready_line: Any = None) -> None:
        await starter()
        await stopper()

    monkeypatch.setattr(can, "Bus", counting_bus)
    monkeypatch.setattr(serve, "run_until_signal", start_and_stop)
    cfg = write_config(tmp_path / "plant.yaml", {"interface": "virtual", "channel": unique_channel()})
    assert entry_main(["run", "-c", str(cfg), "--no-simulate"]) == 0, capsys.readouterr().err
    assert [k["interface"] for k in opened] == ["virtual"]
