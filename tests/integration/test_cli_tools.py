"""The command line as an installer and a commissioning engineer meet it: an interface name
python-can cannot load is one line at ``check`` and ``run`` (exit 2, no traceback), ``remote``
works on a plain install, and ``sdo``/``nmt`` run beside a gateway that holds the ports, with
the values of an SDO server that is not ours (python canopen's LocalNode)."""

from __future__ import annotations

import socket
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
import yaml

from canopen_gateway.bus.can_backend import installed_interfaces, interface_problem
from canopen_gateway.cli import format_sdo_int, main
from canopen_gateway.profiles import load_profile
from tests.helpers import free_port, unique_channel

REPO = Path(__file__).resolve().parents[2]
WIRE = {"name": "wire", "node_id": 5, "profile": "sgh10", "configure": False}


def write_config(tmp_path: Path, **sections: Any) -> Path:
    cfg: dict[str, Any] = {
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 0, "probe_at_start": False},
        "nodes": [WIRE],
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": []},
    }
    cfg.update(sections)
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return path


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "canopen_gateway", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )


# --------------------------------------------------------------------------- interfaces


def test_python_can_remote_is_a_main_dependency_so_interface_remote_works_on_a_plain_install() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert "python-can-remote==0.3.0" in project["dependencies"]
    assert "remote" in installed_interfaces()
    assert interface_problem("remote") is None


@pytest.mark.parametrize("command", ["check", "run"])
def test_unknown_interface_is_one_line_naming_it_and_the_installed_ones_exit_2(
    tmp_path: Path, command: str
) -> None:
    path = write_config(tmp_path, can={"interface": "nosuchcan", "channel": "x"})
    r = cli(command, "-c", str(path))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"{path}: can.interface: unknown CAN interface 'nosuchcan'")
    assert "installed python-can interfaces:" in lines[0]
    for name in ("remote", "socketcan", "virtual"):
        assert name in lines[0]
    assert r.stdout == ""


def test_check_accepts_interface_remote(tmp_path: Path) -> None:
    path = write_config(tmp_path, can={"interface": "remote", "channel": "ws://127.0.0.1:1/"})
    r = cli("check", "-c", str(path))
    assert r.returncode == 0, r.stderr
    assert f"{path}: OK" in r.stdout


def test_a_misspelt_interface_gets_a_did_you_mean_before_the_list() -> None:
    problem = interface_problem("virtul")
    assert problem is not None
    assert problem.startswith(
        "unknown CAN interface 'virtul' (not installed); did you mean 'virtual'? "
        "installed python-can interfaces: "
    )
    far = interface_problem("zzzzzz")
    assert far is not None and "did you mean" not in far


def test_an_installed_name_whose_module_cannot_be_imported_is_not_usable(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(can.interfaces.BACKENDS, "ghost", ("gateway_no_such_module", "GhostBus"))
    problem = interface_problem("ghost")
    assert problem is not None
    assert problem.startswith("CAN interface 'ghost' is not usable on this install")
    assert "gateway_no_such_module" in problem


# --------------------------------------------------------------------------- sdo / nmt


@contextmanager
def local_node(channel: str, node_id: int) -> Iterator[canopen.LocalNode]:
    """An SGH10 object dictionary served by python canopen (an SDO server that is not ours)."""
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(node_id, str(load_profile("sgh10").eds_path))
    network.add_node(node)
    try:
        yield node
    finally:
        network.disconnect()


@contextmanager
def port_taken() -> Iterator[int]:
    """A listening socket on a loopback port, as a running gateway's health endpoint holds."""
    port = free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        yield port


def test_sdo_beside_a_running_gateway_opens_no_server_and_prints_negatives_in_twos_complement(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with port_taken() as health_port, port_taken() as modbus_port:
        path = write_config(
            tmp_path,
            health={"host": "127.0.0.1", "port": health_port},
            modbus={"enabled": True, "host": "127.0.0.1", "port": modbus_port},
        )
        channel = yaml.safe_load(path.read_text(encoding="utf-8"))["can"]["channel"]
        with local_node(channel, 5) as node:
            node.sdo[0x6020][1].raw = -677  # position, int32 (SGH10 manual 4.7)
            assert main(["sdo", "read", "-c", str(path), "wire", "0x6020:01"]) == 0
            assert capsys.readouterr().out.strip() == "-677 (0xFFFFFD5B)"
            assert main(["sdo", "read", "-c", str(path), "wire", "0x1018:01"]) == 0
            assert capsys.readouterr().out.strip() == "405 (0x00000195)"
            assert main(["sdo", "read", "-c", str(path), "5", "0x6020:01", "--type", "int16"]) == 0
            assert capsys.readouterr().out.strip() == "-677 (0xFD5B)"


def test_nmt_beside_a_running_gateway_opens_no_server(tmp_path: Path) -> None:
    with port_taken() as health_port:
        path = write_config(tmp_path, health={"host": "127.0.0.1", "port": health_port})
        channel = yaml.safe_load(path.read_text(encoding="utf-8"))["can"]["channel"]
        bus = can.Bus(interface="virtual", channel=channel)
        try:
            assert main(["nmt", "-c", str(path), "stop", "wire"]) == 0
            frames = []
            while (msg := bus.recv(timeout=0)) is not None:
                frames.append(msg)
        finally:
            bus.shutdown()
    assert [bytes(m.data).hex(" ") for m in frames if m.arbitration_id == 0x000] == ["02 05"]


@pytest.mark.parametrize(
    ("value", "type_", "text"),
    [
        (-677, "int32", "-677 (0xFFFFFD5B)"),
        (-1, "int8", "-1 (0xFF)"),
        (-2, "int24", "-2 (0xFFFFFE)"),
        (-(1 << 63), "int64", f"{-(1 << 63)} (0x8000000000000000)"),
        (405, "uint32", "405 (0x00000195)"),
        (200, "uint8", "200 (0xC8)"),
        (-677, None, "-677 (0xFD5B)"),
        (300, None, "300 (0x012C)"),
        (-3, None, "-3 (0xFD)"),
    ],
)
def test_sdo_integers_print_in_hex_of_the_objects_width(
    value: int, type_: str | None, text: str
) -> None:
    assert format_sdo_int(value, type_) == text
