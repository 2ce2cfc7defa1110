"""mbpoll (libmodbus, the Debian package) as the PLC: reads 32-bit integers and floats in both
word orders, text and bits, writes a control word and a set point reaching the simulated AP05,
and reports the gateway's exception codes. Several mbpoll processes at once."""

from __future__ import annotations

import asyncio
import contextlib
import re
import shutil
from collections.abc import AsyncIterator

import pytest

from canopen_gateway.app import Gateway
from tests.helpers import gateway_of, make_config, wait_until

pytestmark = pytest.mark.skipif(
    shutil.which("mbpoll") is None,
    reason="mbpoll is not installed (Debian package mbpoll; `make test` installs it)",
)

NODES = [
    {"name": "wire", "node_id": 1, "profile": "sgh10"},
    {
        "name": "wire2",
        "node_id": 2,
        "profile": "sgh10",
        "signals": {"position": {"as_float": True, "word_order": "little"}},
    },
    {"name": "display", "node_id": 125, "profile": "ap05"},
]
HOLD = {"kind": "hold", "min": -5000, "max": 5000, "hold": -1234}


@contextlib.asynccontextmanager
async def running() -> AsyncIterator[Gateway]:
    motion = {"wire": HOLD, "wire2": HOLD}
    cfg = make_config(NODES, zenoh={"enabled": False}, simulate={"nodes": "all", "motion": motion})
    gw = gateway_of(cfg)
    await gw.start()
    try:
        for n in NODES:
            node = gw.image.nodes[n["name"]]
            await wait_until(
                lambda node=node: node.operational() and node.signals["position"].seq, 5, n["name"]
            )
        yield gw
    finally:
        await gw.stop()


async def mbpoll(gw: Gateway, *args: str, values: list[str] | None = None) -> tuple[int, str]:
    """Run mbpoll once against the gateway (PDU addresses, ``-0``); (exit code, output)."""
    cmd = ["mbpoll", "-m", "tcp", "-p", str(gw.modbus.port), "-0", "-1", "-o", "2", *args]
    cmd += ["127.0.0.1"] + (["--", *values] if values else [])
    proc = await asyncio.create_subprocess_exec(
        *cmd, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT
    )
    out, _ = await asyncio.wait_for(proc.communicate(), 10)
    assert proc.returncode is not None
    return proc.returncode, out.decode(errors="replace")


def values(out: str) -> dict[int, str]:
    """``[100]: 	-1234`` lines -> {100: "-1234"}."""
    return {int(a): v.strip() for a, v in re.findall(r"^\[(\d+)\]:\s+(\S+)", out, re.M)}


async def test_mbpoll_reads_int32_float_text_and_bits() -> None:
    async with running() as gw:
        rc, out = await mbpoll(gw, "-a", "1", "-r", "100", "-t", "3:int", "-B")
        assert rc == 0 and values(out) == {100: "-1234"}, out
        rc, out = await mbpoll(gw, "-a", "2", "-r", "100", "-t", "3:float")  # low word first
        assert rc == 0 and float(values(out)[100]) == pytest.approx(-123.4, abs=1e-3), out
        rc, out = await mbpoll(gw, "-a", "1", "-r", "147", "-c", "3", "-t", "4:hex")
        assert values(out) == {147: "0x5347", 148: "0x4831", 149: "0x3000"}, out  # "SGH10"
        rc, out = await mbpoll(gw, "-a", "125", "-r", "0", "-c", "4", "-t", "1")
        assert values(out) == {0: "1", 1: "1", 2: "1", 3: "0"}, out


async def test_mbpoll_writes_reach_the_ap05() -> None:
    async with running() as gw:
        sim = gw.sim.nodes["display"]
        rc, out = await mbpoll(gw, "-a", "125", "-r", "106", "-t", "4", values=["4"])
        assert rc == 0, out
        await wait_until(
            lambda: gw.sim.runner.call(lambda now: sim.get(0x5F0C, 0)) & ~0x100 == 4, 2, "5F0Ch"
        )
        rc, out = await mbpoll(gw, "-a", "125", "-r", "100", "-t", "4:int", "-B", values=["-12345"])
        assert rc == 0, out
        await wait_until(
            lambda: (
                gw.sim.runner.call(lambda now: sim.get(0x5F16, 3)) & 0xFFFFFFFF
                == -12345 & 0xFFFFFFFF
            ),
            2,
            "5F16h:03",
        )
        rc, out = await mbpoll(gw, "-a", "125", "-r", "100", "-c", "16", "-t", "1")
        assert values(out)[102] == "1", "status bit 2: set point1 valid (control bit 2)"


async def test_mbpoll_reports_the_gateway_exception_codes() -> None:
    async with running() as gw:
        rc, out = await mbpoll(gw, "-a", "1", "-r", "50", "-t", "3")
        assert rc != 0 and "Illegal data address" in out, out
        rc, out = await mbpoll(gw, "-a", "125", "-r", "120", "-t", "4", values=["9"])
        assert rc != 0 and "Illegal data value" in out, out
        rc, out = await mbpoll(gw, "-a", "1", "-r", "111", "-t", "4", values=["5"])
        assert rc != 0 and "Slave device or server failure" in out, out
        rc, out = await mbpoll(gw, "-a", "99", "-r", "0", "-t", "3")
        assert rc != 0 and "Gateway path unavailable" in out, out


async def test_several_mbpoll_clients_at_once() -> None:
    async with running() as gw:
        runs = await asyncio.gather(
            *(
                mbpoll(gw, "-a", str(unit), "-r", "0", "-c", "4", "-t", "3")
                for unit in (1, 2, 125, 1, 2, 125)
            )
        )
        for rc, out in runs:
            assert rc == 0, out
            assert values(out)[1] == "5", "NMT operational"
