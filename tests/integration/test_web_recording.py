"""The console's bus recording over real HTTP: ``/api/monitor/record?seconds=S&format=F``
answers, after S seconds, a trace file of what the gateway received meanwhile, in python-can's
writer of that format, which ``canopen-gateway decode`` reads back in CANopen words (frames
scripted from the SGH10 manual on a second python-can bus); the tap exists only while it
records; a bad format or duration is a 400 in words."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from canopen_gateway.cli import main
from tests.helpers import wait_until
from tests.integration.test_traces import SCRIPT
from tests.integration.test_web_http import http
from tests.integration.test_web_monitor import gateway


async def test_a_recording_downloads_as_a_trace_that_decode_reads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async with gateway() as (gw, device, addr):
        request = asyncio.ensure_future(http(f"http://{addr}/api/monitor/record?seconds=1&format=blf"))
        await wait_until(lambda: len(gw.driver.frame_taps) == 1, 5, "the recording's tap")
        for msg in SCRIPT:
            device.send(msg)
        code, headers, body = await request
        assert code == 200, body
        assert headers["Content-Disposition"].startswith('attachment; filename="') and ".blf" in headers["Content-Disposition"]
        await wait_until(lambda: gw.driver.frame_taps == (), 5, "the tap removed")
        trace = tmp_path / "bus.blf"
        trace.write_bytes(body)
        config = tmp_path / "cfg.yaml"
        config.write_text("can: {interface: virtual}\nnodes: [{name: wire, node_id: 1, profile: sgh10}]\n")
        assert main(["decode", "-c", str(config), str(trace)]) == 0
        out = capsys.readouterr().out
        assert "wire" in out and "position=1234.5 mm" in out and "EMCY" in out and "heartbeat" in out


@pytest.mark.parametrize("query", ["?format=pcap", "?seconds=0", "?seconds=61", "?seconds=x"])
async def test_a_bad_format_or_duration_is_a_400_in_words(query: str) -> None:
    async with gateway() as (gw, _, addr):
        code, _, body = await http(f"http://{addr}/api/monitor/record{query}")
        assert code == 400 and b"asc, blf, trc, log, csv" in body
        assert gw.driver.frame_taps == ()
