"""systemd notification without a library (``canopen_gateway.runtime.sd_notify``) on a real AF_UNIX
datagram socket: the watchdog is ours only when WATCHDOG_PID is unset or our pid, its period
half of WATCHDOG_USEC; no ping while the CAN reader (any network's) stands still; an abstract socket name
(``@name``); nothing at all without NOTIFY_SOCKET. And the JSON log lines
(``canopen_gateway.runtime.logformat``): the fields, the node a line concerns, a bad
CANOPEN_GATEWAY_LOG_FORMAT named."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import socket
from pathlib import Path

import pytest

from canopen_gateway.cli import main
from canopen_gateway.runtime.logformat import JsonFormatter
from canopen_gateway.runtime.sd_notify import SystemdNotifier


def test_watchdog_period_is_half_of_watchdog_usec_when_the_pid_is_ours_or_unset() -> None:
    env = {"NOTIFY_SOCKET": "/run/x", "WATCHDOG_USEC": "10000000"}
    assert SystemdNotifier.from_env(env).watchdog_s == 5.0
    assert SystemdNotifier.from_env({**env, "WATCHDOG_PID": str(os.getpid())}).watchdog_s == 5.0
    assert SystemdNotifier.from_env({**env, "WATCHDOG_PID": "1"}, pid=4242).watchdog_s is None
    assert SystemdNotifier.from_env({"NOTIFY_SOCKET": "@sd"}).address == "\0sd"
    none = SystemdNotifier.from_env({"WATCHDOG_USEC": "10000000"})
    assert not none and none.watchdog_s is None and none.send("READY=1") is False


def test_pings_come_every_half_of_watchdog_usec_on_time_beside_the_status_period() -> None:
    """WatchdogSec=3: a ping every 1.5 s, not every 2 s (the status period rounding it up)."""
    from canopen_gateway.runtime.sd_notify import Cadence

    cadence, now, pings, looks = Cadence(1.5, 100.0), 100.0, [], []
    while now < 106.0:
        ping, look, wait_s = cadence.turn(now)
        pings += [round(now - 100.0, 3)] if ping else []
        looks += [round(now - 100.0, 3)] if look else []
        assert 0.0 < wait_s <= 1.0
        now += wait_s
    assert pings == [0.0, 1.5, 3.0, 4.5]
    assert looks == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    no_watchdog = Cadence(None, 0.0)
    assert no_watchdog.turn(0.0) == (False, True, 1.0)


async def test_pings_only_while_alive_and_status_only_when_it_changes(tmp_path: Path) -> None:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "n.sock"))
    sock.setblocking(False)
    notifier = SystemdNotifier(str(tmp_path / "n.sock"), watchdog_s=0.001)
    alive = iter([True, False, False, True])
    turns: list[bool] = []

    def is_alive() -> bool:
        turns.append(next(alive, True))
        return turns[-1]

    task = asyncio.get_running_loop().create_task(notifier.supervise(is_alive, lambda: "ok"))
    got: list[str] = []
    while got.count("WATCHDOG=1") < 2:
        got += (await asyncio.get_running_loop().sock_recv(sock, 4096)).decode().split("\n")
    task.cancel()
    notifier.stopping()
    got += (await asyncio.get_running_loop().sock_recv(sock, 4096)).decode().split("\n")
    sock.close()
    assert got.count("STATUS=ok") == 1  # sent once, not at every turn
    assert turns[:4] == [True, False, False, True]  # the two pings: the 1st and 4th turns
    assert got[-2:] == ["STOPPING=1", "STATUS=stopping"]


def test_the_watchdog_needs_every_networks_reader_to_go_round() -> None:
    """With several CAN networks one stuck reader (or a dead one) is a gateway systemd
    restarts: the others going round do not hide it."""
    from types import SimpleNamespace

    from canopen_gateway.cli.serve import readers_go_round

    line1, line2 = (SimpleNamespace(name=n, driver=SimpleNamespace(reader_turns=0)) for n in ("line1", "line2"))
    failures: dict[str, str] = {}
    alive = readers_go_round(SimpleNamespace(networks=[line1, line2], threads=SimpleNamespace(failures=lambda: failures)))
    assert alive()  # the first ask: nothing to compare with yet
    line1.driver.reader_turns += 1
    assert not alive()  # line2's reader stood still
    line1.driver.reader_turns += 1
    line2.driver.reader_turns += 1
    assert alive()
    line1.driver.reader_turns += 1
    line2.driver.reader_turns += 1
    failures["can-reader-line2"] = "OSError"
    assert not alive()


def record(msg: str, *args: object, **extra: object) -> logging.LogRecord:
    r = logging.LogRecord("gateway.master", logging.WARNING, __file__, 1, msg, args, None)
    r.__dict__.update(extra)
    return r


def test_json_lines_carry_time_level_logger_message_and_the_node() -> None:
    fmt = JsonFormatter()
    doc = json.loads(fmt.format(record("node %s (id 1): %s", "wire", "no boot-up")))
    assert doc["level"] == "warning" and doc["logger"] == "gateway.master"
    assert doc["message"] == "node wire (id 1): no boot-up" and doc["node"] == "wire"
    assert doc["time"].endswith("Z") and "T" in doc["time"]
    assert json.loads(fmt.format(record("node display: lost")))["node"] == "display"
    assert json.loads(fmt.format(record("values", node="magnet")))["node"] == "magnet"
    assert "node" not in json.loads(fmt.format(record("CAN bus reopened")))


def test_a_rate_limited_line_about_a_node_carries_the_node_in_json(caplog: pytest.LogCaptureFixture) -> None:
    """The bus-peer lines ("another SDO client talks to node wire ...") go through the rate
    limit; the node is given with them, so a JSON line names it."""
    from canopen_gateway.runtime.ratelimit import RateLimitedLog

    limited = RateLimitedLog(logging.getLogger("gateway.master"), period_s=10.0, clock=lambda: 0.0)
    with caplog.at_level(logging.INFO, logger="gateway.master"):
        limited.info(("sdo_client", "wire"), "%s", "another SDO client talks to node wire (id 1): upload", extra={"node": "wire"})  # fmt: skip
    (rec,) = caplog.records
    assert json.loads(JsonFormatter().format(rec))["node"] == "wire"


def test_an_unknown_log_format_in_the_environment_is_named(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("CANOPEN_GATEWAY_LOG_FORMAT", "xml")
    assert main(["run", "-c", "config/demo.yaml"]) == 2
    assert "CANOPEN_GATEWAY_LOG_FORMAT='xml': allowed: text, json" in capsys.readouterr().err
