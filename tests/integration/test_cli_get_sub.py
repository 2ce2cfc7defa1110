"""``canopen-gateway get`` and ``sub``: a running gateway's Zenoh keys read from the command
line with the connect settings of its config, one line per reply or sample (key, then the
payload as sent); an error reply on stderr with exit 1; a config without Zenoh is exit 2."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
import yaml

from canopen_gateway.app import Gateway
from canopen_gateway.checks import load_checked
from canopen_gateway.cli import main
from tests.helpers import free_port, node_operational, unique_channel, wait_until


@pytest.fixture
async def running(tmp_path: Path) -> AsyncIterator[Path]:
    raw = {
        "gateway": {"name": "line"},
        "can": {"interface": "virtual", "channel": unique_channel()},
        "master": {"heartbeat_ms": 200, "heartbeat_timeout_multiple": 3},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"enabled": False},
        "zenoh": {"listen": [f"tcp/0.0.0.0:{free_port()}"]},  # the command reads it as 127.0.0.1
        "simulate": {"nodes": "all"},
        "journal": {"path": str(tmp_path / "journal")},
    }
    path = tmp_path / "line.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    gw = Gateway(*load_checked(path))
    await gw.start()
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        await wait_until(lambda: gw.image.nodes["wire"].signals["position"].seq > 0, 5, "a position")
        yield path
    finally:
        await gw.stop()


async def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, list[str], list[str]]:
    code = await asyncio.to_thread(main, list(args))
    out, err = capsys.readouterr()
    return code, out.splitlines(), err.splitlines()


async def test_get_and_sub_read_the_keys_as_the_cloud_does(running: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = await cli(capsys, "get", "-c", str(running), "wire/value/position")
    assert (code, err, len(out)) == (0, [], 1)
    key, _, payload = out[0].partition(" ")
    assert key == "canopen/line/wire/value/position"
    assert json.loads(payload)["quality"] == "good" and json.loads(payload)["unit"] == "mm"
    code, out, _ = await cli(capsys, "get", "-c", str(running), "/canopen/*/catalog")  # as written
    assert code == 0 and out[0].startswith('canopen/line/catalog {"gateway": "line"')
    code, out, err = await cli(capsys, "get", "-c", str(running), "nosuch/value/x")
    assert (code, out) == (1, [])
    assert err[0].startswith("error: canopen/line/nosuch/value/x: ") and '"node_unknown"' in err[0]
    # history with nothing in the range: an empty answer, as Zenoh storages give it, not an error
    code, out, err = await cli(capsys, "get", "-c", str(running), "wire/emcy?_time=[now(-30)..]")
    assert (code, out) == (0, []) and err == ["canopen/line/wire/emcy?_time=[now(-30)..]: no history in that range (the gateway answered nothing)"]  # fmt: skip
    code, out, err = await cli(capsys, "sub", "-c", str(running), "wire/value/*", "--count", "2")
    assert (code, err, len(out)) == (0, [], 2)
    assert all(line.startswith("canopen/line/wire/value/") for line in out)


def test_a_config_without_zenoh_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "off.yaml"
    path.write_text("can: {interface: virtual}\nzenoh: {enabled: false}\n", encoding="utf-8")
    assert main(["get", "-c", str(path), "wire/state"]) == 2
    assert capsys.readouterr().err == f"error: {path}: zenoh.enabled is false: the gateway serves no Zenoh keys\n"
