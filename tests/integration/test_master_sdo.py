"""SDO client against simulated devices on a virtual bus: expedited and segmented transfers,
aborts with their code and DS-301 text, timeouts and retries, one transfer per node at a time
with several nodes in parallel; and ``canopen-gateway sdo`` run as a subprocess."""

from __future__ import annotations

import asyncio
import subprocess
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import can
import pytest
import yaml

from canopen_gateway.app import Gateway
from canopen_gateway.errors import NodeNotOperational, SdoAbort, SdoTimeout
from tests.helpers import gateway_of, make_config, unique_channel, wait_until

REPO = Path(__file__).resolve().parents[2]
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
MAGNET = {"name": "magnet", "node_id": 2, "profile": "msk5000"}


@asynccontextmanager
async def running(nodes: list[dict[str, Any]], **sections: Any) -> AsyncIterator[Gateway]:
    cfg = make_config(nodes, modbus={"enabled": False}, zenoh={"enabled": False}, **sections)
    gw = gateway_of(cfg)
    await gw.start()
    try:
        for name in gw.master.nodes:
            await wait_until(lambda n=name: gw.image.nodes[n].operational(), 5, f"{name} up")
        yield gw
    finally:
        await gw.stop()


async def test_segmented_upload_of_the_device_name_is_cut_at_the_trailing_nul() -> None:
    async with running([WIRE]) as gw:
        # SGH10 manual 4.4.1.4: 1008h "SGH10" by segmented upload (the last segment pads 00h)
        assert await gw.commands.sdo_read("wire", "0x1008:00") == "SGH10"
        raw = await gw.commands.sdo_read("wire", "0x1008:00", "bytes")
        assert raw.rstrip(b"\0") == b"SGH10"


async def test_expedited_upload_and_download_round_trip() -> None:
    async with running([WIRE]) as gw:
        assert await gw.commands.sdo_read("wire", "0x1018:01") == 0x195  # vendor id, 4.6
        await gw.commands.sdo_write("wire", "0x6200:00", 25)
        assert await gw.commands.sdo_read("wire", "0x6200:00") == 25
        assert gw.sim.nodes["wire"].get(0x1800, 5) == 25  # 6200h is 1800h:05


@pytest.mark.parametrize(
    ("op", "obj", "value", "code"),
    [
        ("read", "0x6FFF:00", None, 0x06020000),  # object does not exist
        ("write", "0x1000:00", 1, 0x06010002),  # read-only
        ("write", "0x1008:00", "ABCDEFGH", 0x06010002),  # segmented initiate, refused
    ],
)
async def test_sdo_abort_surfaces_with_its_code_and_text(
    op: str, obj: str, value: Any, code: int
) -> None:
    async with running([WIRE]) as gw:
        with pytest.raises(SdoAbort) as err:
            if op == "read":
                await gw.commands.sdo_read("wire", obj)
            else:
                await gw.commands.sdo_write(
                    "wire", obj, value, "string" if isinstance(value, str) else None
                )
        assert err.value.code == code
        assert f"0x{code:08X}" in str(err.value)
        assert err.value.text and err.value.text in str(err.value)
        assert err.value.obj == obj.upper().replace("0X", "0x")
        assert gw.image.nodes["wire"].health.last_sdo_abort == code


async def test_timeout_retries_as_configured_then_aborts_naming_the_object() -> None:
    async with running([WIRE], master={"sdo_timeout_s": 0.1, "sdo_retries": 2}) as gw:
        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.silence())
        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            with pytest.raises(SdoTimeout, match="no SDO response from node wire for 0x1018:01"):
                await gw.commands.sdo_read("wire", "0x1018:01")
            frames: list[bytes] = []
            while not frames or frames[-1][0] != 0x80:  # up to the abort frame
                m = await asyncio.to_thread(bus.recv, 2.0)
                assert m is not None, f"no abort frame after {frames}"
                if m.arbitration_id == 0x601:
                    frames.append(bytes(m.data))
        finally:
            bus.shutdown()
        # three initiate requests (first + 2 retries), then the abort naming 1018h:01 with
        # 05040000h "SDO protocol timed out" (CiA 301 7.2.4.3.17)
        request = bytes.fromhex("4018100100000000")
        assert frames == [request] * 3 + [bytes.fromhex("8018100100000405")]


async def test_lost_node_refuses_sdo_without_waiting_for_a_timeout() -> None:
    async with running([WIRE]) as gw:
        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.silence())
        await wait_until(lambda: not gw.image.nodes["wire"].health.alive, 2, "wire lost")
        with pytest.raises(NodeNotOperational):
            await gw.commands.sdo_read("wire", "0x1000:00")


async def test_one_transfer_per_node_at_a_time_and_nodes_in_parallel() -> None:
    async with running([WIRE, MAGNET], master={"sdo_timeout_s": 3.0, "sdo_retries": 0}) as gw:
        wire_reads = ["0x1018:01", "0x1000:00", "0x1017:00", "0x1008:00", "0x1018:04"]
        expected = [await gw.commands.sdo_read("wire", o) for o in wire_reads]
        # concurrent requests to one node are serialised: every answer belongs to its request
        got = await asyncio.gather(*(gw.commands.sdo_read("wire", o) for o in wire_reads * 2))
        assert got == expected * 2
        # a node that does not answer does not hold up another one: the reads of wire are
        # all answered while the transfer to magnet still waits for its timeout
        magnet = gw.sim.nodes["magnet"]
        gw.sim.runner.call(lambda now: magnet.silence())
        slow = asyncio.create_task(gw.commands.sdo_read("magnet", "0x1000:00"))
        for _ in range(3):
            assert await gw.commands.sdo_read("wire", "0x1018:01") == 0x195
        assert not slow.done()
        with pytest.raises(SdoTimeout):
            await slow


# --------------------------------------------------------------------------- the CLI


def _config_file(tmp_path: Path) -> Path:
    cfg = {
        "can": {"interface": "virtual", "channel": unique_channel()},
        "nodes": [WIRE],
        "modbus": {"enabled": False},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": "all"},
    }
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return path


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "canopen_gateway", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=30,
    )


def test_cli_sdo_read_prints_the_value_and_write_reports_an_abort(tmp_path: Path) -> None:
    path = str(_config_file(tmp_path))
    r = _cli("sdo", "read", "-c", path, "wire", "0x1008:00")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "SGH10"
    r = _cli("sdo", "write", "-c", path, "wire", "0x1000:00", "1")
    assert r.returncode == 1
    assert "SDO abort 0x06010002" in r.stderr
    assert "0x1000:00" in r.stderr
