"""The console's bus monitor over real HTTP on 127.0.0.1: a running gateway, frames scripted
from the SGH10 and AP05 manuals on a second python-can ``virtual`` bus (a TPDO decoded with the
profile's signal names, an EMCY with the device's text, another tool's SDO request answered by
an abort with its text), read from ``/api/monitor/stream`` with filters by node and kind; the
reader's tap exists only while a stream is open; bad filters are 400 in words."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import can
import pytest

from canopen_gateway.app import Gateway
from canopen_gateway.web.monitor import MAX_LINES_PER_S
from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.integration.test_web_first_hour import get_json

TIMEOUT_S = 10.0


@asynccontextmanager
async def gateway() -> AsyncIterator[tuple[Gateway, can.BusABC, str]]:
    """wire (SGH10, id 1) and display (AP05, id 125) configured, not simulated: every frame on
    the bus comes from the test's own bus."""
    cfg = make_config(
        [
            {"name": "wire", "node_id": 1, "profile": "sgh10"},
            {"name": "display", "node_id": 125, "profile": "ap05"},
        ],
        health={"port": free_port()},
        modbus={"enabled": False},
        zenoh={"enabled": False},
        simulate={"nodes": []},
    )
    gw = gateway_of(cfg)
    await gw.start()
    device = can.Bus(interface="virtual", channel=cfg.can.channel)
    try:
        yield gw, device, f"127.0.0.1:{gw.health.port}"
    finally:
        device.shutdown()
        await gw.stop()


def send(bus: can.BusABC, cob_id: int, data: bytes) -> None:
    bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))


class EventStream:
    """A server-sent event stream read line by line (HTML Living Standard 9.2)."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.reader, self.writer = reader, writer

    async def next(self) -> tuple[str, Any]:
        event, data = "message", ""
        while True:
            line = (await asyncio.wait_for(self.reader.readline(), TIMEOUT_S)).decode()
            assert line, "the stream ended"
            line = line.rstrip("\n")
            if not line:
                if data:
                    return event, json.loads(data)
                continue
            field, _, value = line.partition(": ")
            if field == "event":
                event = value
            elif field == "data":
                data = value

    async def frames_until(self, done: Any) -> list[dict[str, Any]]:
        """Lines of ``frames`` events until ``done(lines)`` is true."""
        got: list[dict[str, Any]] = []
        while not done(got):
            event, data = await self.next()
            if event == "frames":
                got.extend(data)
        return got

    def close(self) -> None:
        self.writer.close()


async def open_stream(addr: str, query: str = "") -> tuple[EventStream, dict[str, Any]]:
    host, port = addr.split(":")
    reader, writer = await asyncio.open_connection(host, int(port))
    writer.write(f"GET /api/monitor/stream{query} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    await writer.drain()
    head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), TIMEOUT_S)
    assert b"200 OK" in head and b"text/event-stream" in head
    stream = EventStream(reader, writer)
    event, hello = await stream.next()
    assert event == "hello"  # the page is open: the tap is installed
    return stream, hello


async def test_the_monitor_streams_a_tpdo_an_emcy_and_an_sdo_abort_in_canopen_words() -> None:
    async with gateway() as (gw, device, addr):
        assert gw.driver.frame_taps == ()  # no page open: the reader only checks it
        stream, hello = await open_stream(addr)
        assert hello["max_lines_per_s"] == MAX_LINES_PER_S and hello["direction"] == "received"
        assert len(gw.driver.frame_taps) == 1
        # SGH10 manual: TPDO1 = position (int32, 0.1 mm) + velocity (int16)
        send(device, 0x181, (98765).to_bytes(4, "little", signed=True) + (-12).to_bytes(2, "little", signed=True))
        # AP05 manual 5.5.1 table 31: FF12h speed error, error register 81h
        send(device, 0x0FD, bytes([0x12, 0xFF, 0x81, 0, 0, 0, 0, 0]))
        # another tool uploads 6000h:00 from wire; wire answers with an abort
        send(device, 0x601, bytes([0x40, 0x00, 0x60, 0x00, 0, 0, 0, 0]))
        send(device, 0x581, bytes([0x80, 0x00, 0x60, 0x00, 0x00, 0x00, 0x02, 0x06]))
        lines = await stream.frames_until(lambda got: len(got) >= 4)
        stream.close()
        texts = [(f["cob_id"], f["node"], f["kind"], f["service"], f["text"]) for f in lines]
        assert texts[0] == ("181", "wire", "pdo", "TPDO1", "position=9876.5 mm velocity=-12 mm/s")
        assert texts[1][:4] == ("0FD", "display", "emcy", "EMCY")
        assert texts[1][4] == (
            "0xFF12 (Speed error (admissible speed exceeded)), error register 0x81 "
            "[generic, manufacturer specific], manufacturer 00 00 00 00 00"
        )
        assert texts[2] == ("601", "wire", "sdo", "SDO request", "upload 0x6000:00 (Operating parameters)")
        assert texts[3] == (
            "581", "wire", "sdo", "SDO answer",
            "abort 0x6000:00 (Operating parameters): 0x06020000 Object does not exist in the "
            "object dictionary",
        )  # fmt: skip
        assert lines[0]["data"] == "cd 81 01 00 f4 ff" and lines[0]["dir"] == "rx"
        await wait_until(lambda: gw.driver.frame_taps == (), TIMEOUT_S, "the tap removed")


async def test_filters_by_node_and_kind_are_applied_by_the_gateway() -> None:
    async with gateway() as (gw, device, addr):
        emcy, hello = await open_stream(addr, "?kind=emcy")
        assert hello["filter"] == {"node": None, "kind": ["emcy"]}
        wire, hello = await open_stream(addr, "?node=wire")
        assert hello["filter"] == {"node": [1], "kind": None}
        for i in range(3):
            send(device, 0x181, i.to_bytes(4, "little") + bytes(2))
        send(device, 0x77D, b"\x05")  # display heartbeat: operational
        send(device, 0x081, bytes([0x10, 0x50, 0x01, 0, 0, 0, 0, 0]))  # wire EMCY 5010h
        send(device, 0x0FD, bytes([0x00, 0x00, 0x00, 0, 0, 0, 0, 0]))  # display: error reset
        got_emcy = await emcy.frames_until(lambda got: len(got) >= 2)
        got_wire = await wire.frames_until(lambda got: len(got) >= 4)
        assert [(f["node"], f["kind"]) for f in got_emcy] == [("wire", "emcy"), ("display", "emcy")]
        assert [(f["node"], f["kind"]) for f in got_wire] == [("wire", "pdo")] * 3 + [("wire", "emcy")]
        emcy.close()
        wire.close()
        await wait_until(lambda: not gw.web.monitor.pages, TIMEOUT_S, "both pages closed")
        assert gw.driver.frame_taps == ()


async def test_a_flood_is_shown_at_most_the_limit_a_second_with_the_skipped_counted() -> None:
    async with gateway() as (gw, device, addr):
        gw.web.monitor._clock = lambda: 0.0  # a frozen clock: every frame in the same second
        stream, _ = await open_stream(addr, "?node=wire&kind=pdo")
        n = 3 * MAX_LINES_PER_S
        for i in range(n):
            send(device, 0x181, i.to_bytes(4, "little") + bytes(2))
        send(device, 0x77D, b"\x05")  # filtered out: neither counted nor skipped
        got = await stream.frames_until(
            lambda got: sum(1 if "text" in f else f["skipped"] for f in got) >= n
        )
        stream.close()
        shown = [f for f in got if "text" in f]
        skipped = sum(f["skipped"] for f in got if "skipped" in f)
        assert len(shown) == MAX_LINES_PER_S and skipped == n - MAX_LINES_PER_S
        # the first of the second, in order
        values = [float(f["text"].split("=")[1].split()[0]) for f in shown]
        assert values == [i / 10 for i in range(MAX_LINES_PER_S)]
        assert "skipped" in got[-1]


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ("?node=pump", "node: 'pump': not a node of the config (wire, display) nor a node id 1..127"),
        ("?kind=pdos", "kind: pdos: kinds are nmt, sync, time, emcy, pdo, sdo, heartbeat, lss, other"),
    ],
)
async def test_an_unknown_node_or_kind_is_a_400_in_words(query: str, message: str) -> None:
    async with gateway() as (gw, _, addr):
        code, doc = await get_json(f"http://{addr}/api/monitor/stream{query}")
        assert code == 400 and doc == {"error": "bad_request", "message": message}
        assert gw.driver.frame_taps == ()


async def test_the_monitor_page_is_served_and_linked_from_the_overview() -> None:
    async with gateway() as (_, _, addr):
        from tests.integration.test_web_http import http

        code, _, body = await http(f"http://{addr}/monitor")
        assert code == 200 and b'data-page="monitor"' in body
        code, _, body = await http(f"http://{addr}/")
        assert b'href="/monitor"' in body
