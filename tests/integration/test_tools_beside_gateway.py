"""``sdo`` and ``nmt`` on a config whose bus is the in-process ``virtual`` bus, as a new user
runs them beside a running gateway: they go through the gateway's command socket (a Unix
socket only its user can open) and reach its devices, with Zenoh writes off as they are by
default (the write is seen by the gateway, the NMT stop in its /healthz); a gateway without
its command socket is reached through its Zenoh API, whose refusal of a write says what to do;
without either way in they refuse in one line that says how to reach the gateway; with no
gateway running they say that they act on their own simulated devices."""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.helpers import free_port, gateway_running, unique_channel, wait_until_sync

REPO = Path(__file__).resolve().parents[2]


def demo_like(path: Path, **sections: Any) -> Path:
    """A config like config/demo.yaml (virtual bus, simulated devices, Zenoh writes on) on
    free ports."""
    raw: dict[str, Any] = {
        "gateway": {"name": "demo"},
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 200},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"], "writes": True},
        "health": {"port": free_port()},
        "simulate": {"nodes": "all"},
    }
    raw.update(sections)
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "canopen_gateway", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )


def healthz(cfg: Path) -> dict[str, Any]:
    port = yaml.safe_load(cfg.read_text(encoding="utf-8"))["health"]["port"]
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=5) as r:
        return json.loads(r.read())


@pytest.fixture(scope="module")
def running(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A user's own config: the demo's devices, Zenoh on, its writes off (the default)."""
    cfg = demo_like(
        tmp_path_factory.mktemp("demo") / "demo.yaml",
        zenoh={"listen": [f"tcp/127.0.0.1:{free_port()}"]},
    )
    with gateway_running(cfg):
        yield cfg


def test_sdo_goes_through_the_running_gateways_command_socket(running: Path) -> None:
    r = cli("sdo", "read", "-c", str(running), "wire", "0x1008:00")
    assert (r.returncode, r.stdout.strip()) == (0, "SGH10"), r.stderr
    assert r.stderr.startswith("sdo read of wire through the running gateway at its command socket /")
    # a write reaches the gateway's devices: read back by another process, through it again
    r = cli("sdo", "write", "-c", str(running), "wire", "0x6000:00", "4")
    assert (r.returncode, r.stdout.strip()) == (0, "OK"), r.stderr
    r = cli("sdo", "read", "-c", str(running), "wire", "0x6000:00")
    assert (r.returncode, r.stdout.strip()) == (0, "4 (0x0004)"), r.stderr
    r = cli("sdo", "write", "-c", str(running), "wire", "0x1000:00", "1")
    assert r.returncode == 1
    assert r.stderr.startswith("error: SDO abort 0x06010002 (Attempt to write a read only object)")
    assert "through the running gateway at its command socket /" in r.stderr


def test_nmt_without_zenoh_writes_goes_through_the_command_socket(running: Path) -> None:
    r = cli("nmt", "-c", str(running), "stop", "wire")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("NMT stop sent to wire through the running gateway at its command socket /")
    # the device's next heartbeat reports it stopped (bounded wait on /healthz)
    wait_until_sync(
        lambda: healthz(running)["nodes"]["wire"]["nmt_state"] == "stopped", 10, "wire stopped"
    )
    r = cli("nmt", "-c", str(running), "start", "all")
    assert r.returncode == 0, r.stderr


def test_the_command_socket_is_the_gateway_users_alone(running: Path) -> None:
    from canopen_gateway.checks import load_checked
    from canopen_gateway.command_socket import socket_paths

    cfg, _ = load_checked(running)
    path = next(p for p in socket_paths(cfg) if p.exists())
    st, dst = path.lstat(), path.parent.lstat()
    assert stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o600
    assert stat.S_IMODE(dst.st_mode) == 0o700 and st.st_uid == dst.st_uid == os.getuid()
    assert path.name.startswith("demo-") and path.name.endswith(".sock")


async def test_a_gateway_without_its_command_socket_is_reached_by_zenoh_and_a_refused_write_says_what_to_do(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import asyncio

    from canopen_gateway.app import Gateway
    from canopen_gateway.checks import load_checked
    from canopen_gateway.cli import main

    cfg_file = demo_like(tmp_path / "z.yaml", zenoh={"listen": [f"tcp/127.0.0.1:{free_port()}"]},
                         command_socket={"enabled": False})  # fmt: skip
    gw = Gateway(*load_checked(cfg_file))
    await gw.start()
    try:
        assert gw.command_socket.path is None
        assert await asyncio.to_thread(main, ["sdo", "read", "-c", str(cfg_file), "wire", "0x1008:00"]) == 0
        out = capsys.readouterr()
        assert out.out.strip() == "SGH10" and "through the running gateway at tcp/127.0.0.1:" in out.err
        assert await asyncio.to_thread(main, ["nmt", "-c", str(cfg_file), "stop", "wire"]) == 1
    finally:
        await gw.stop()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("error: Zenoh writes are off on this gateway")
    assert err[0].endswith(
        "; no command socket of this gateway (command_socket.enabled is false in this config): run "
        "this command as the gateway's user with the config file it runs, on a gateway with its "
        "command socket on (the default with an in-process bus; docs/web.md), or open Zenoh "
        "writes (zenoh.writes: on), which opens them to every Zenoh client"
    )


def test_without_zenoh_beside_a_running_gateway_the_command_refuses_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from canopen_gateway.cli import main

    with socket.socket() as held:  # the running gateway's health port
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        cfg = demo_like(tmp_path / "g.yaml", zenoh={"enabled": False}, health={"port": port})
        with pytest.raises(SystemExit) as exc:
            main(["sdo", "write", "-c", str(cfg), "wire", "0x6000:00", "4"])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(
        f"error: {cfg}: can.interface: virtual: the bus lives inside the gateway running at "
        f"http://127.0.0.1:{port}, so `sdo write` would act on a private copy of the devices"
    )
    assert "can.interface: remote, docs/canopen.md" in lines[0]
    assert "or start it with its command socket (command_socket.enabled, the default;" in lines[0]


def test_with_no_gateway_running_the_command_says_it_acts_on_its_own_devices(
    tmp_path: Path,
) -> None:
    cfg = demo_like(tmp_path / "alone.yaml")
    r = cli("sdo", "read", "-c", str(cfg), "wire", "0x1008:00")
    assert (r.returncode, r.stdout.strip()) == (0, "SGH10"), r.stderr
    assert r.stderr.strip() == (
        f"note: {cfg}: can.interface: virtual and no gateway runs on this config: acting on this "
        "command's own simulated devices (wire)"
    )


def test_a_tool_on_a_shared_bus_sends_no_heartbeat_and_no_sync(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Beside a gateway on a shared bus the tool is a second master only for what it is asked:
    no heartbeat on the gateway's COB-ID (the gateway would report another master), no SYNC
    (synchronous TPDOs would be sent twice as often)."""
    import can
    import canopen

    from canopen_gateway.cli import main
    from canopen_gateway.profiles import load_profile

    cfg = demo_like(
        tmp_path / "shared.yaml",
        zenoh={"enabled": False},
        simulate={"nodes": []},
        master={"heartbeat_ms": 100, "sync_period_ms": 50},
    )
    channel = yaml.safe_load(cfg.read_text(encoding="utf-8"))["can"]["channel"]
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    watcher = can.Bus(interface="virtual", channel=channel)
    try:
        network.add_node(canopen.LocalNode(1, str(load_profile("sgh10").eds_path)))
        assert main(["sdo", "read", "-c", str(cfg), "wire", "0x1008:00"]) == 0
        assert capsys.readouterr().out.strip() == "SGH10"
        seen = set()
        while (msg := watcher.recv(timeout=0)) is not None:
            seen.add(msg.arbitration_id)
    finally:
        watcher.shutdown()
        network.disconnect()
    assert 0x601 in seen and 0x581 in seen  # the SDO exchange itself
    assert 0x77F not in seen and 0x080 not in seen


@pytest.mark.parametrize("command", [["scan"], ["monitor", "--count", "1"], ["lss", "inquire"]])
def test_listening_tools_beside_a_gateway_on_an_in_process_bus_refuse_in_one_line(
    running: Path, command: list[str]
) -> None:
    r = cli(*command, "-c", str(running))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(
        f"error: {running}: can.interface: virtual: the bus lives inside the gateway"
    )
    assert f"so `{command[0]}`" in lines[0] and "can.interface: remote, docs/canopen.md" in lines[0]
    assert "zenoh" not in lines[0]  # only sdo and nmt go through the gateway's Zenoh API
    if command[0] == "monitor":  # the running gateway's console shows its bus
        assert "/monitor)" in lines[0]
    else:  # its commissioning page scans; off in that gateway: how to turn it on
        port = yaml.safe_load(running.read_text(encoding="utf-8"))["health"]["port"]
        assert (
            f"use its web console's commissioning page (http://127.0.0.1:{port}/commissioning), "
            "which that gateway serves when started with web.writes and a token: "
            "CANOPEN_GATEWAY__WEB__WRITES=true CANOPEN_GATEWAY__WEB__TOKEN='a long random text' "
            f"canopen-gateway run -c {running};"
        ) in lines[0]


async def test_scan_beside_a_gateway_that_serves_its_commissioning_page_points_at_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import asyncio

    from canopen_gateway.app import Gateway
    from canopen_gateway.checks import load_checked
    from canopen_gateway.cli import main

    cfg_file = demo_like(tmp_path / "w.yaml", web={"writes": True, "token": "a long random text"})
    gw = Gateway(*load_checked(cfg_file))
    await gw.start()
    try:
        with pytest.raises(SystemExit) as exc:
            await asyncio.to_thread(main, ["scan", "-c", str(cfg_file)])
    finally:
        await gw.stop()
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"use its web console's commissioning page (http://127.0.0.1:{gw.cfg.health.port}/commissioning);" in lines[0]
    assert "CANOPEN_GATEWAY__WEB__WRITES" not in lines[0]


async def test_fault_finds_the_web_port_a_variable_moved_through_the_command_socket(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The gateway runs with its health port moved by a variable of its own shell; `fault` in
    another shell, with the file alone, reaches it without --url."""
    import asyncio

    from canopen_gateway.app import Gateway
    from canopen_gateway.checks import load_checked
    from canopen_gateway.cli import main

    cfg_file = demo_like(tmp_path / "f.yaml", zenoh={"enabled": False})
    moved = free_port()
    gw = Gateway(*load_checked(cfg_file, environ={"CANOPEN_GATEWAY__HEALTH__PORT": str(moved)}))
    await gw.start()
    try:
        assert gw.health.port == moved
        assert await asyncio.to_thread(main, ["fault", "-c", str(cfg_file), "wire", "heartbeat-off"]) == 0
        assert capsys.readouterr().out.startswith("wire: heartbeat-off done")
    finally:
        await gw.stop()
