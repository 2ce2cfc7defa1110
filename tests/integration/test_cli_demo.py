"""A gateway never pretends: ``run`` without its configuration file exits 2 with one line
naming the path and saying to mount one (the image's command without a mounted config); the
demo runs only when asked for, by ``demo`` or ``CANOPEN_GATEWAY_DEMO=1``, on the file
``CANOPEN_GATEWAY_DEMO_CONFIG`` names (the image's) or a checkout's ``config/demo.yaml``."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from canopen_gateway.cli import build_parser, main, serve
from tests.helpers import free_port, stop_process

ROOT = Path(__file__).resolve().parents[2]
IMAGE_CONFIG = "/etc/canopen-gateway/config.yaml"


def test_run_without_its_config_file_exits_2_in_one_line_saying_to_mount_one(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("CANOPEN_GATEWAY_DEMO", raising=False)
    if Path(IMAGE_CONFIG).exists():
        pytest.skip(f"{IMAGE_CONFIG} exists on this machine")
    assert main(["run", "-c", IMAGE_CONFIG]) == 2  # the image's path (not on this machine)
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"error: {IMAGE_CONFIG}: no configuration file there: mount yours at this path")
    assert "canopen-gateway demo" in line and "CANOPEN_GATEWAY_DEMO=1" in line
    missing = str(tmp_path / "config.yaml")  # any other path: no container advice
    assert main(["run", "-c", missing]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"error: {missing}: no configuration file there: check the path") and "docker" not in line


def test_the_demo_command_runs_the_demo_configuration(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[str] = []
    monkeypatch.setattr(serve, "cmd_run", lambda args: seen.append(args.config) or 0)
    args = build_parser().parse_args(["demo"])
    monkeypatch.delenv("CANOPEN_GATEWAY_DEMO_CONFIG", raising=False)
    assert serve.cmd_demo(args) == 0
    monkeypatch.setenv("CANOPEN_GATEWAY_DEMO_CONFIG", "/etc/canopen-gateway/demo.yaml")
    assert serve.cmd_demo(argparse.Namespace(log_level=None)) == 0
    assert seen == ["config/demo.yaml", "/etc/canopen-gateway/demo.yaml"]
    assert (ROOT / "config/demo.yaml").is_file()


def demo_on_free_ports(tmp_path: Path) -> Path:
    """The demo config on free ports and its own virtual channel, written under ``tmp_path``."""
    demo = yaml.safe_load((ROOT / "config/demo.yaml").read_text())
    demo["modbus"]["port"] = free_port()
    demo["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    demo["health"]["port"] = free_port()
    demo["can"]["channel"] = f"demo-{demo['modbus']['port']}"
    (tmp_path / "demo.yaml").write_text(yaml.safe_dump(demo))
    return tmp_path / "demo.yaml"


def test_the_demo_command_starts_the_gateway_in_either_log_format(tmp_path: Path) -> None:
    """``canopen-gateway demo`` (the image's documented command), text and JSON lines: the
    banner of a gateway that started (the whole path of ``run``, not a stand-in)."""
    env = {"CANOPEN_GATEWAY_DEMO_CONFIG": str(demo_on_free_ports(tmp_path)), "PATH": "/usr/bin:/bin"}
    for extra in ([], ["--log-format", "json"]):
        proc = subprocess.Popen([sys.executable, "-m", "canopen_gateway", "demo", *extra], cwd=ROOT,
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            if extra:
                doc = json.loads(line)
                assert "canopen-gateway" in doc["message"] and "'demo'" in doc["message"], line
            else:
                assert "canopen-gateway" in line and "'demo'" in line and "(sim)" in line, line
        finally:
            stop_process(proc)


def test_canopen_gateway_demo_1_makes_the_images_command_run_the_demo(tmp_path: Path) -> None:
    env = {"CANOPEN_GATEWAY_DEMO": "1", "CANOPEN_GATEWAY_DEMO_CONFIG": str(demo_on_free_ports(tmp_path)),
           "PATH": "/usr/bin:/bin"}  # fmt: skip
    proc = subprocess.Popen([sys.executable, "-m", "canopen_gateway", "run", "-c", IMAGE_CONFIG], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert "canopen-gateway" in line and "'demo'" in line and "(sim)" in line, line
    finally:
        stop_process(proc)
