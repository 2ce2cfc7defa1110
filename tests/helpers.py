"""Test helpers: a gateway built from a config dict on a private virtual CAN channel, with
Modbus and Zenoh on free loopback ports (``modbus_gateway``: started, with a connected Modbus
client), CAN frames (``frame``), and helpers that wait on conditions (bounded). The fixtures
of ``tests/conftest.py`` hand out the same."""

from __future__ import annotations

import asyncio
import itertools
import socket
import threading
import time
import uuid
from collections.abc import AsyncIterator, Callable, Iterable, Iterator
from contextlib import asynccontextmanager, contextmanager
from pathlib import Path
from typing import Any

import can

from canopen_gateway.checks import load_checked, parse_checked

_port_counter = itertools.count()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port: int) -> bool:
    """Something listens on 127.0.0.1:``port``."""
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def start_can_remote(port: int, channel: str) -> Any:
    """python-can-remote's server on the virtual bus ``channel``, in a process of its own on
    127.0.0.1:``port`` (not yet listening: wait for ``port_open``)."""
    import subprocess
    import sys

    return subprocess.Popen(
        [sys.executable, "-m", "can_remote", "-i", "virtual", "-c", channel,
         "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def wait_can_remote(proc: Any, port: int) -> None:
    """Until ``start_can_remote``'s server listens (bounded); it must not have exited."""
    wait_until_sync(lambda: port_open(port) or proc.poll() is not None, 30, f"port {port}")
    assert proc.poll() is None, f"python-can-remote on port {port} exited: {proc.returncode}"


@contextmanager
def can_remote_server(port: int, channel: str) -> Iterator[Any]:
    """``start_can_remote``, listening when entered; ended on exit."""
    proc = start_can_remote(port, channel)
    try:
        wait_can_remote(proc, port)
        yield proc
    finally:
        stop_process(proc)


def unique_channel() -> str:
    return f"test-{uuid.uuid4().hex[:10]}"


def make_config(nodes: list[dict[str, Any]], **sections: Any) -> Any:
    """A validated Config for tests: private virtual bus, free ports, every node simulated."""
    raw: dict[str, Any] = {
        "gateway": {"name": "test"},
        "can": {"interface": "virtual", "channel": unique_channel()},
        # a consumer timeout of 3 heartbeat periods: a starved test machine does not lose nodes
        # (the timeout edges themselves are tested on a fake clock, tests/unit)
        "master": {"heartbeat_ms": 200, "sync_period_ms": 50, "boot_timeout_s": 5,
                   "heartbeat_timeout_multiple": 3},
        "nodes": nodes,
        "modbus": {"port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"]},
        "simulate": {"nodes": "all"},
    }
    for k, v in sections.items():
        if isinstance(v, dict) and isinstance(raw.get(k), dict):
            raw[k] = {**raw[k], **v}
        else:
            raw[k] = v
    return parse_checked_config(raw, environ={})


def parse_checked_config(raw: Any, source: str = "<memory>", environ: Any = None) -> Any:
    """``canopen_gateway.checks.parse_checked``'s config alone (a test resolves its nodes when it needs
    them: ``resolved``)."""
    return parse_checked(raw, source, environ).cfg


def load_checked_config(path: Any, environ: Any = None) -> Any:
    """``canopen_gateway.checks.load_checked``'s config alone."""
    return load_checked(path, environ).cfg


def resolved(cfg: Any) -> Any:
    """The nodes of a bare Config, resolved (``canopen_gateway.device.resolved``), for a test that builds
    a consumer (Master, ModbusGateway, the register map...) from it."""
    from canopen_gateway.device.resolved import resolve_nodes

    return resolve_nodes(cfg)[0]


def with_nodes(cfg: Any) -> tuple[Any, Any]:
    """``(cfg, resolved(cfg))``: ``all_keys(*with_nodes(cfg))``."""
    return cfg, resolved(cfg)


def gateway_of(cfg: Any, *args: Any, **kw: Any) -> Any:
    """``Gateway(cfg, nodes, ...)`` with the nodes of ``cfg`` resolved (``resolved``)."""
    from canopen_gateway.app import Gateway

    return Gateway(cfg, resolved(cfg), *args, **kw)


def simulated_bus(cfg: Any, names: list[str] | None = None) -> Any:
    """``SimulatedBus(cfg, nodes, names)`` with the nodes of ``cfg`` resolved (``resolved``)."""
    from canopen_gateway.sim.buses import SimulatedBus

    return SimulatedBus(cfg, resolved(cfg), names)


def wait_until_sync(cond: Callable[[], Any], timeout_s: float = 5.0, what: str = "condition") -> Any:
    """``wait_until`` for code outside the event loop (threads, other processes): poll
    ``cond`` every 10 ms until truthy; fail the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not (v := cond()):
        assert time.monotonic() < deadline, f"timed out after {timeout_s} s waiting for {what}"
        threading.Event().wait(0.01)
    return v


async def wait_until(cond: Callable[[], Any], timeout_s: float = 5.0, what: str = "condition") -> Any:
    """Poll ``cond`` every 10 ms until truthy; fail the test after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(0.01)


@asynccontextmanager
async def master_running(nodes: list[dict[str, Any]], **sections: Any) -> AsyncIterator[Any]:
    """A Gateway with only the CANopen side (no Modbus, no Zenoh), stopped on exit."""

    cfg = make_config(nodes, modbus={"enabled": False}, zenoh={"enabled": False}, **sections)
    gw = gateway_of(cfg)
    await gw.start()
    try:
        yield gw
    finally:
        await gw.stop()


def operational(name: str) -> Callable[[Any], bool]:
    """Condition for ``modbus_gateway``: node ``name`` is operational."""
    return lambda gw: gw.image.nodes[name].operational()


def with_position(name: str) -> Callable[[Any], bool]:
    """Condition for ``modbus_gateway``: node ``name`` is operational and sent a position."""

    def cond(gw: Any) -> bool:
        node = gw.image.nodes[name]
        return bool(node.operational() and node.signals["position"].seq > 0)

    return cond


def node_operational(gw: Any, name: str) -> bool:
    """Configured, NMT operational and alive."""
    from canopen_gateway.bus.node.lifecycle import LifecycleState
    from canopen_gateway.image import NmtState

    rt = gw.master.nodes[name]
    return (
        rt.lifecycle.state == LifecycleState.OPERATIONAL
        and rt.image.health.nmt_state == NmtState.OPERATIONAL
        and rt.image.health.alive
    )


def frame(
    cob_id: int, data: bytes | str = b"", *, rtr: bool = False, dlc: int = 0, **kw: Any
) -> can.Message:
    """A standard (11-bit) CAN frame; ``data`` as bytes or as hex text (``"05 00"``); a remote
    frame (``rtr``) asks for ``dlc`` bytes."""
    raw = bytes.fromhex(data) if isinstance(data, str) else bytes(data)
    return can.Message(
        arbitration_id=cob_id,
        data=raw,
        is_extended_id=False,
        is_remote_frame=rtr,
        dlc=dlc if rtr else len(raw),
        **kw,
    )


@asynccontextmanager
async def modbus_gateway(
    cfg: Any, ready: Iterable[tuple[Callable[[Any], Any], str]] = ()
) -> AsyncIterator[tuple[Any, Any]]:
    """A started gateway of ``cfg`` and a pymodbus client connected to its Modbus server; each
    ``(condition(gateway), what)`` of ``ready`` is waited for (5 s each) before the body runs.
    Both are stopped on exit."""
    from pymodbus.client import AsyncModbusTcpClient

    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
    try:
        await client.connect()
        for cond, what in ready:
            await wait_until(lambda cond=cond: cond(gw), 5, what)
        yield gw, client
    finally:
        client.close()
        await gw.stop()
def gateway_process(config: Any, *args: str) -> Any:
    """``canopen-gateway run -c config`` as a separate process (stdout and stderr piped)."""
    import subprocess
    import sys
    from pathlib import Path

    return subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "run", "-c", str(config), "--log-level", "warning", *args],
        cwd=Path(__file__).resolve().parents[1],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def stop_process(proc: Any, *, thaw: bool = False) -> None:
    """End a process a test started: SIGTERM, then SIGKILL after 10 s; ``thaw``: a process the
    test may have frozen (SIGSTOP) is sent SIGCONT first, or it could not act on the SIGTERM."""
    import os
    import signal
    import subprocess

    if proc.poll() is None:
        if thaw:
            os.kill(proc.pid, signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()


def wait_ready(proc: Any, timeout_s: float = 60.0) -> str:
    """The summary line a gateway process prints once everything listens (bounded wait)."""
    import selectors

    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sel.select(timeout=deadline - time.monotonic()):
            line = proc.stdout.readline()
            if line:
                return line
            raise AssertionError(f"gateway exited before it was ready: {proc.wait()}")
    raise AssertionError("gateway did not become ready")


@contextmanager
def gateway_running(config: Any, *args: str) -> Iterator[Any]:
    """A gateway process on ``config``, ready (its summary line printed); stopped on exit."""
    proc = gateway_process(config, *args)
    try:
        wait_ready(proc)
        yield proc
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def edited_copy(tmp_path: Path, src: Path, old: str, new: str, name: str = "edited.eds") -> Path:
    """A copy of the device file ``src`` in ``tmp_path`` with the first ``old`` made ``new``."""
    text = src.read_text(encoding="utf-8")
    assert old in text, old
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1), encoding="utf-8")
    return p


def line_of(path: Path, text: str) -> int:
    """The number of the first line of ``path`` that is ``text`` (stripped)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return next(i for i, line in enumerate(lines, start=1) if line.strip() == text)
