"""The gateway under a service manager and a log shipper, as a real process: with
``NOTIFY_SOCKET`` (a real AF_UNIX datagram socket, as systemd makes it) it says ``READY=1`` once
the health port accepts, ``STATUS=`` lines, ``WATCHDOG=1`` every half of ``WATCHDOG_USEC`` and
``STOPPING=1`` at SIGTERM; with ``CANOPEN_GATEWAY_LOG_FORMAT=json`` every line it writes, the
start-up banner included, is one JSON object with time, level, logger, message (and node)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from tests.helpers import free_port, unique_channel

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 60.0  # bounded waits for a loaded machine; nothing is timed


def receive(sock: socket.socket, until: str, got: list[str]) -> list[str]:
    """Datagrams (each split into its lines) until one has the line ``until``."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            lines = sock.recv(4096).decode().split("\n")
        except TimeoutError:
            break
        got += lines
        if until in lines:
            return got
    raise AssertionError(f"no {until} within {WAIT_S} s; got {got}")


@pytest.fixture(scope="module")
def service_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """One gateway run under a fake systemd: what it notified, wrote and how it ended."""
    tmp = tmp_path_factory.mktemp("service")
    health = free_port()
    cfg = {
        "gateway": {"name": "svc"},
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 0},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"port": free_port()},
        "zenoh": {"enabled": False},
        "health": {"port": health},
        "simulate": {"nodes": ["wire"]},
    }
    path = tmp / "gw.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp / "notify.sock"))
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp / "notify.sock"), "WATCHDOG_USEC": "200000",
           "CANOPEN_GATEWAY_LOG_FORMAT": "json"}  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "run", "-c", str(path), "--log-level", "info"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    run: dict[str, Any] = {}
    try:
        got = receive(sock, "READY=1", [])
        with socket.create_connection(("127.0.0.1", health), timeout=5):
            run["health_accepting_at_ready"] = True
        receive(sock, "WATCHDOG=1", got)
        receive(sock, "WATCHDOG=1", got)
        run["before_stop"] = list(got)
        proc.send_signal(signal.SIGTERM)
        receive(sock, "STOPPING=1", got)
        run["notified"] = got
        out, err = proc.communicate(timeout=WAIT_S)
        run.update(returncode=proc.returncode, stdout=out, stderr=err)
        yield run
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        sock.close()


def test_ready_comes_once_the_health_port_accepts_with_a_status(service_run: dict[str, Any]) -> None:
    got = service_run["notified"]
    assert service_run["health_accepting_at_ready"]
    ready = got.index("READY=1")
    assert got[ready + 1].startswith("STATUS=") and "nodes operational" in got[ready + 1]
    assert got[0] == "STATUS=starting"


def test_watchdog_pings_while_running_and_stopping_at_sigterm(service_run: dict[str, Any]) -> None:
    got = service_run["notified"]
    assert service_run["before_stop"].count("WATCHDOG=1") >= 2
    assert "STOPPING=1" not in service_run["before_stop"]
    assert "STOPPING=1" in got
    assert service_run["returncode"] == 0


def test_every_line_is_one_json_object_banner_included(service_run: dict[str, Any]) -> None:
    out_lines = [line for line in service_run["stdout"].splitlines() if line.strip()]
    err_lines = [line for line in service_run["stderr"].splitlines() if line.strip()]
    assert out_lines and err_lines
    docs = [json.loads(line) for line in out_lines + err_lines]
    for doc in docs:
        assert {"time", "level", "logger", "message"} <= set(doc), doc
        assert doc["time"].endswith("Z") and doc["level"] in ("debug", "info", "warning", "error")
    banner = json.loads(out_lines[0])
    assert "wire" in banner["message"] and banner["logger"] == "gateway"
    assert any(d.get("node") == "wire" for d in docs), docs
    assert any("stopped in" in d["message"] for d in docs)
