"""The README's first hour as a new user copies it: every command it names is a whole command
(``canopen-gateway ...`` with its ``-c``), the parser takes it, and the ones on the demo's
config run, in the README's order, against a running demo (config/demo.yaml on free ports)."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from canopen_gateway.cli import build_parser
from tests.helpers import free_port, gateway_running, unique_channel

ROOT = Path(__file__).resolve().parents[2]


def first_hour_spans() -> list[str]:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme.split("## The first hour", 1)[1].split("\n## ", 1)[0]
    return [" ".join(s.split()) for s in re.findall(r"`([^`]+)`", section)]


def commands() -> list[str]:
    return [s for s in first_hour_spans() if s.startswith("canopen-gateway ")]


def test_every_command_of_the_first_hour_is_whole_and_parses() -> None:
    parser = build_parser()
    names = set(next(a for a in parser._actions if a.dest == "command").choices)  # type: ignore[arg-type]
    for span in first_hour_spans():
        # a fragment like `nmt stop wire` or `run` cannot be copied and run
        assert span.split()[0] not in names, f"not a whole command: `{span}`"
    assert len(commands()) >= 8
    for command in commands():
        args = parser.parse_args(shlex.split(command)[1:])  # exits 2 on a missing -c
        assert args.config, command


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    raw = yaml.safe_load((ROOT / "config/demo.yaml").read_text(encoding="utf-8"))
    raw["can"]["channel"] = unique_channel()
    raw["modbus"]["port"] = free_port()
    raw["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    raw["health"]["port"] = free_port()
    path = tmp_path_factory.mktemp("demo") / "demo.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    with gateway_running(path):
        yield path


def test_the_first_hour_commands_on_the_demo_run_against_the_running_demo(demo: Path) -> None:
    on_demo = [c for c in commands() if "-c config/demo.yaml" in c]
    assert [shlex.split(c)[1] for c in on_demo] == ["sdo", "nmt", "nmt", "fault", "fault"]
    for command in on_demo:
        argv = shlex.split(command.replace("config/demo.yaml", str(demo)))[1:]
        r = subprocess.run(
            [sys.executable, "-m", "canopen_gateway", *argv],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 0, f"{command}: {r.stderr}"
        if argv[0] == "sdo":
            assert r.stdout.strip() == "SGH10"
