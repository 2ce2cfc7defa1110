"""The small things a new user meets in the first hour: a closed pipe (``check | head -1``) and
Ctrl-C during start-up end the program without a traceback; an unknown node is an argument
error (exit 2); a token of digits is refused by one rule; log lines read as sentences; the
console has a favicon; the start-up line names the journal."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import types
import urllib.request
from pathlib import Path

import pytest

from canopen_gateway.bus.error_control.supervision import InvalidStateByte, ToggleError, WrongState
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.cli import _count
from canopen_gateway.config import ConfigError, parse_config
from canopen_gateway.entry import main as entry_main
from tests.helpers import free_port, master_running

REPO = Path(__file__).resolve().parents[2]


def test_a_closed_pipe_ends_check_quietly() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "check", "-c", "config/demo.yaml"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    proc.stdout.close()  # the reader is gone before the first line (as `| head -1` after it)
    _, err = proc.communicate(timeout=60)
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert proc.returncode == 0


def test_ctrl_c_while_importing_is_exit_130_without_traceback(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    class Interrupted(types.ModuleType):
        def __getattr__(self, name: str) -> object:
            raise KeyboardInterrupt  # Ctrl-C while `from canopen_gateway.cli import main` runs

    monkeypatch.setitem(sys.modules, "canopen_gateway.cli", Interrupted("canopen_gateway.cli"))
    assert entry_main(["check", "-c", "config/demo.yaml"]) == 130


def test_ctrl_c_right_after_start_leaves_no_traceback() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "run", "-c", "config/demo.yaml"],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    proc.send_signal(signal.SIGINT)  # during interpreter start or the imports
    _, err = proc.communicate(timeout=60)
    assert "Traceback" not in err, err
    assert proc.returncode in (130, -signal.SIGINT)


def test_sdo_read_of_an_unknown_node_is_an_argument_error(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from canopen_gateway.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["sdo", "read", "-c", str(REPO / "config/demo.yaml"), "nosuch", "0x1000:00"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"error: no node 'nosuch' in {REPO / 'config/demo.yaml'}; nodes: wire (id 1), "
    )


def test_a_token_of_digits_is_refused_by_one_rule_from_the_file_and_from_the_environment() -> None:
    rule = (
        "a token of digits only is refused, in the file (quoted or not) as in "
        'CANOPEN_GATEWAY__WEB__TOKEN: mix in letters (token: "a long random text")'
    )
    with pytest.raises(ConfigError) as exc:
        parse_config({"web": {"writes": True, "token": 123456789012345}}, "cfg.yaml", environ={})
    assert exc.value.problems == [f"cfg.yaml: web.token: YAML read a number here; {rule}"]
    with pytest.raises(ConfigError) as exc:
        parse_config({"web": {"writes": True, "token": "0123456789012"}}, "cfg.yaml", environ={})
    assert exc.value.problems == [f"cfg.yaml: web.token: {rule}"]
    # the same value from the environment: the same rule, blamed on the variable
    with pytest.raises(ConfigError) as exc:
        parse_config({"web": {"writes": True}}, "cfg.yaml", environ={"CANOPEN_GATEWAY__WEB__TOKEN": "0123456789012"})
    assert exc.value.problems == [f"CANOPEN_GATEWAY__WEB__TOKEN: web.token: {rule}"]
    for quoted in ("'123456789012345'", '"123456789012345"'):  # quoted as in a file: the same digits
        with pytest.raises(ConfigError) as exc:
            parse_config({"web": {"writes": True}}, "cfg.yaml", environ={"CANOPEN_GATEWAY__WEB__TOKEN": quoted})
        assert exc.value.problems == [f"CANOPEN_GATEWAY__WEB__TOKEN: web.token: {rule}"]
    # taken as written, leading zero included, when it has letters
    cfg = parse_config(
        {"web": {"writes": True}}, "cfg.yaml", environ={"CANOPEN_GATEWAY__WEB__TOKEN": "0123456789012x"}
    )
    assert cfg.web.token == "0123456789012x"


def test_counts_and_supervision_findings_read_as_words() -> None:
    assert _count(1, "process signal") == "1 process signal"
    assert _count(2, "process signal") == "2 process signals"
    assert _count(0, "configuration object") == "0 configuration objects"
    assert str(WrongState(NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL, 2)) == (
        "guarding answer reports pre-operational, expected operational (2 in a row)"
    )
    assert str(ToggleError(expected=0, received=1, count=1)) == (
        "guarding answer toggle bit 1, expected 0 (1 in a row)"
    )
    assert (
        str(InvalidStateByte(0x33)) == "state byte 0x33 is not an NMT state (DS-301: 0, 4, 5, 127)"
    )


async def test_console_serves_a_favicon() -> None:
    import asyncio

    port = free_port()
    async with master_running(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}], health={"port": port}
    ):

        def fetch(path: str) -> tuple[int, str, bytes]:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
                return r.status, r.headers["Content-Type"], r.read()

        for path in ("/favicon.ico", "/static/favicon.svg"):
            status, ctype, body = await asyncio.to_thread(fetch, path)
            assert (status, ctype) == (200, "image/svg+xml") and body.startswith(b"<svg")
        _, _, page = await asyncio.to_thread(fetch, "/")
        assert b'<link rel="icon" href="/static/favicon.svg"' in page


async def test_the_start_up_line_and_the_log_say_the_journal_is_on_and_where(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    import logging

    from tests.helpers import gateway_of, make_config

    caplog.set_level(logging.INFO, logger="gateway")
    cfg = make_config([{"name": "wire", "node_id": 1, "profile": "sgh10"}], zenoh={"enabled": False},
                      journal={"path": str(tmp_path / "journal"), "values_ms": 0})  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    try:
        where = tmp_path / "journal" / "journal.sqlite3"
        assert f" | journal {where} | " in gw.summary()
    finally:
        await gw.stop()
    assert f"journal on: {where} (events only, kept 30 days, at most 256 MB)" in caplog.messages


def test_lss_takes_its_action_words_after_c_as_the_readme_writes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``canopen-gateway lss switch-global -c FILE waiting``: the word after ``-c`` is the
    action's (argparse took it for an unknown argument); an unknown option is still refused."""
    from canopen_gateway.cli import main

    cfg = tmp_path / "lss.yaml"
    cfg.write_text(
        f"can: {{interface: virtual, channel: lss-order-{os.getpid()}}}\n"
        "nodes: [{name: wire, node_id: 1, profile: sgh10}]\nzenoh: {enabled: false}\nhealth: {port: 0}\n"
    )
    assert main(["lss", "switch-global", "-c", str(cfg), "waiting"]) == 0
    assert "all slaves to waiting" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exc:
        main(["lss", "inquire", "-c", str(cfg), "--bogus"])
    assert exc.value.code == 2 and "unrecognized arguments: --bogus" in capsys.readouterr().err
