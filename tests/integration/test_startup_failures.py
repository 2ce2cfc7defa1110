"""A gateway that cannot start says why in one line and is gone: a port in use (Modbus, Zenoh
listen, health/web), a file missing. Exit code 2, no traceback, and everything it had opened
before the failure is closed again (ports free, its threads ended), so a service manager can
restart it and a second start on free ports works."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from canopen_gateway.runtime.startup import StartupError
from tests.helpers import (
    free_port,
    gateway_of,
    gateway_process,
    make_config,
    unique_channel,
    wait_ready,
)

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
GATEWAY_THREADS = ("can-reader", "can-sender", "zenoh-publish", "zenoh-events", "sim-runner")


def write_config(path: Path, modbus: int, zenoh: int, health: int) -> Path:
    raw: dict[str, Any] = {
        "gateway": {"name": f"g{zenoh}"},
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 0},
        "nodes": [WIRE],
        "modbus": {"port": modbus},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh}"], "refuse_duplicate_prefix": False},
        "health": {"port": health},
        "simulate": {"nodes": "all"},
    }
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


def port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@pytest.fixture(scope="module")
def first_gateway(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, int]]:
    """A running gateway that holds a Modbus, a Zenoh and a health port."""
    ports = {"modbus": free_port(), "zenoh": free_port(), "health": free_port()}
    cfg = write_config(tmp_path_factory.mktemp("first") / "first.yaml", **ports)
    proc = gateway_process(cfg)
    try:
        wait_ready(proc)
        yield ports
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def another_port(key: str, cfg: Path) -> str:
    """What a port in use says to do: the key in the file, or the variable for one run."""
    var = {"modbus.port": "CANOPEN_GATEWAY__MODBUS__PORT", "health.port": "CANOPEN_GATEWAY__HEALTH__PORT",
           "zenoh.listen": "CANOPEN_GATEWAY__ZENOH__LISTEN"}[key]  # fmt: skip
    value = '\'["tcp/127.0.0.1:<port>"]\'' if key == "zenoh.listen" else "<port>"
    return f"; choose another port: {key} in {cfg}, or {var}={value} for one run"


@pytest.mark.parametrize(
    ("taken", "key", "value"),
    [
        ("modbus", "modbus.port", "{port} on 127.0.0.1"),
        ("zenoh", "zenoh.listen", "tcp/127.0.0.1:{port}"),
        ("health", "health.port", "{port} on 127.0.0.1"),
    ],
)
def test_second_gateway_on_a_port_in_use_exits_2_with_one_line_naming_the_setting(
    first_gateway: dict[str, int], tmp_path: Path, taken: str, key: str, value: str
) -> None:
    ports = {name: free_port() for name in ("modbus", "zenoh", "health")}
    ports[taken] = first_gateway[taken]
    cfg = write_config(tmp_path / "second.yaml", **ports)
    proc = gateway_process(cfg)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == [
        f"error: {cfg}: {key}: {value.format(port=ports[taken])} is already in use "
        f"(another gateway or program listens there){another_port(key, cfg)}"
    ]
    assert out == ""
    # what the second gateway had opened before the failure is closed with it
    for name, port in ports.items():
        if name != taken:
            assert port_free(port), f"{name} port {port} still bound"


async def test_failed_start_closes_every_part_and_ends_every_thread() -> None:
    """In one process: the health port is taken; after ``start()`` raised, the Modbus and Zenoh
    ports it had opened are free, the bus threads and the simulator ended, and a second gateway
    starts on the same ports."""
    before = {t for t in threading.enumerate() if not t.daemon}
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    taken = holder.getsockname()[1]
    zenoh_port, modbus_port = free_port(), free_port()
    sections: dict[str, Any] = {
        "modbus": {"port": modbus_port},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh_port}"]},
        "health": {"port": taken},
    }
    cfg = make_config([WIRE], **sections)
    gw = gateway_of(cfg)
    try:
        with pytest.raises(StartupError) as err:
            await gw.start()
    finally:
        holder.close()
    assert (err.value.key, err.value.value) == ("health.port", f"{taken} on 127.0.0.1")
    assert port_free(modbus_port) and port_free(zenoh_port)
    alive = [t.name for t in threading.enumerate() if t.name in GATEWAY_THREADS and t.is_alive()]
    assert alive == []
    # no thread that would hold the interpreter at exit (the loop's idle executor ends with it)
    held = {t for t in threading.enumerate() if not t.daemon and not t.name.startswith("asyncio_")}
    assert held <= before
    again = gateway_of(make_config([WIRE], **sections))
    await again.start()
    try:
        assert again.started and again.health.port == taken
    finally:
        await again.stop()


async def test_a_start_that_fails_on_a_port_in_use_sends_nothing_to_the_devices() -> None:
    """The listeners start before the master: a gateway that cannot serve leaves the devices
    as they were (no NMT command, no SDO request, no heartbeat of its own on the bus)."""
    import can

    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    taken = holder.getsockname()[1]
    cfg = make_config([WIRE], modbus={"port": free_port()}, health={"port": taken})
    spy = can.Bus(interface="virtual", channel=cfg.can.channel)
    gw = gateway_of(cfg)
    try:
        with pytest.raises(StartupError) as err:
            await gw.start()
        frames = []
        while (msg := spy.recv(0)) is not None:
            frames.append(msg.arbitration_id)
    finally:
        holder.close()
        spy.shutdown()
    assert err.value.key == "health.port"
    master_id = cfg.master.node_id
    sent = [c for c in frames if c == 0x000 or 0x600 < c < 0x680 or c == 0x700 + master_id]
    assert sent == [], [hex(c) for c in sent]


async def test_missing_password_file_names_its_key() -> None:
    cfg = make_config(
        [WIRE],
        zenoh={"auth": {"user": "gw", "password_file": "no-such-password.txt"}},
    )
    gw = gateway_of(cfg)
    with pytest.raises(StartupError) as err:
        await gw.start()
    assert err.value.key == "zenoh.auth.password_file"
    assert str(err.value.value).endswith("no-such-password.txt")
    assert err.value.reason == "does not exist"


def _holders(n: int) -> list[socket.socket]:
    """``n`` ports taken for real: sockets bound and listening on 127.0.0.1."""
    out = []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        s.listen()
        out.append(s)
    return out


def test_every_port_in_use_is_named_in_one_start(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Modbus, Zenoh and health ports all taken: one start says all three, one line each, in
    the order of the config's sections, and exits 2 (not three failed starts for three facts)."""
    from canopen_gateway.cli import main

    holders = _holders(3)
    try:
        modbus, zenoh, health = (h.getsockname()[1] for h in holders)
        cfg = write_config(tmp_path / "busy.yaml", modbus=modbus, zenoh=zenoh, health=health)
        code = main(["run", "-c", str(cfg), "--log-level", "warning"])
    finally:
        for h in holders:
            h.close()
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.splitlines() == [
        f"error: {cfg}: modbus.port: {modbus} on 127.0.0.1 is already in use "
        f"(another gateway or program listens there){another_port('modbus.port', cfg)}",
        f"error: {cfg}: zenoh.listen: tcp/127.0.0.1:{zenoh} is already in use "
        f"(another gateway or program listens there){another_port('zenoh.listen', cfg)}",
        f"error: {cfg}: health.port: {health} on 127.0.0.1 is already in use "
        f"(another gateway or program listens there){another_port('health.port', cfg)}",
    ]


@pytest.mark.parametrize(
    ("key", "variable", "value"),
    [
        ("modbus", "CANOPEN_GATEWAY__MODBUS__PORT", "{port}"),
        ("zenoh", "CANOPEN_GATEWAY__ZENOH__LISTEN", '["tcp/127.0.0.1:{port}"]'),
        ("health", "CANOPEN_GATEWAY__HEALTH__PORT", "{port}"),
    ],
)
def test_a_busy_port_set_by_a_variable_blames_the_variable(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    key: str,
    variable: str,
    value: str,
) -> None:
    """The file says a free port, the variable a busy one: the line names the variable (as
    ``check`` does), not the file whose value is not the one in use."""
    from canopen_gateway.cli import main

    cfg = write_config(tmp_path / "plant.yaml", modbus=free_port(), zenoh=free_port(), health=free_port())
    (holder,) = _holders(1)
    port = holder.getsockname()[1]
    monkeypatch.setenv(variable, value.format(port=port))
    try:
        code = main(["run", "-c", str(cfg), "--log-level", "warning"])
    finally:
        holder.close()
    err = capsys.readouterr().err
    assert code == 2, err
    (line,) = err.splitlines()
    assert line.startswith(f"error: {variable}: "), line
    assert f"{port}" in line and "is already in use" in line
    assert line.endswith(f"; choose another port in {variable}")  # where the value came from
    assert str(cfg) not in line
