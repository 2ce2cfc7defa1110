"""The console's doors over real HTTP on a running gateway: a foreign ``Host`` is answered 421
(the probes' paths answer any), the operators' endpoints (journal, bus monitor, SDO reads,
fault injection) need the token when one is set (by header, or the cookie of ``/api/login``),
wrong tokens are throttled per address with ``Retry-After``, live pages are capped per client
address, and a malformed or repeated ``Content-Length`` is a 400 without a traceback. With
several CAN networks every network's monitor stream and recording is behind the token, and
a client's monitor pages are counted across networks."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.web.access import FAILURES_LIMIT
from canopen_gateway.web.console import LIVE_PER_CLIENT, MONITOR_PER_CLIENT
from tests.helpers import (
    free_port,
    gateway_of,
    make_config,
    node_operational,
    parse_checked_config,
    unique_channel,
    wait_until,
)

TOKEN = "plant-floor-token-42"


def two_networks(**web: Any) -> Any:
    """wire on line1, rotary on line2, each on its own virtual bus, every device simulated."""
    def net(name: str, node: dict[str, Any]) -> dict[str, Any]:
        return {"name": name, "can": {"interface": "virtual", "channel": unique_channel()},
                "master": {"heartbeat_ms": 200, "heartbeat_timeout_multiple": 3}, "nodes": [node]}  # fmt: skip

    return parse_checked_config({
        "gateway": {"name": "two"},
        "networks": [net("line1", {"name": "wire", "node_id": 1, "profile": "sgh10"}),
                     net("line2", {"name": "rotary", "node_id": 5, "profile": "posi_plus"})],
        "modbus": {"enabled": False}, "zenoh": {"enabled": False},
        "health": {"port": free_port()}, "web": web, "simulate": {"nodes": "all"},
    }, environ={})  # fmt: skip


@asynccontextmanager
async def console(cfg: Any = None, **web: Any) -> AsyncIterator[Any]:
    cfg = cfg or make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        health={"port": free_port()}, web=web,
        modbus={"enabled": False}, zenoh={"enabled": False},
    )  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        yield gw
    finally:
        await gw.stop()


async def open_conn(port: int, source: str = "127.0.0.1") -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.0.0.1", port, local_addr=(source, 0))


async def request(port: int, method: str, path: str, headers: dict[str, str] | None = None,
                  body: bytes = b"", source: str = "127.0.0.1", raw_headers: str = "") -> tuple[int, dict[str, str], bytes]:  # fmt: skip
    """One request, its status, headers (lower-case names) and body (streams: the head only)."""
    h = {"Host": f"127.0.0.1:{port}", "Connection": "close", **(headers or {})}
    if body and "Content-Length" not in h and "Content-Length" not in raw_headers:
        h["Content-Length"] = str(len(body))
    head = f"{method} {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in h.items()) + raw_headers
    reader, writer = await open_conn(port, source)
    writer.write(head.encode("latin-1") + b"\r\n" + body)
    await writer.drain()
    status_head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
    lines = status_head.decode("latin-1").split("\r\n")
    got = {k.strip().lower(): v.strip() for k, _, v in (ln.partition(":") for ln in lines[1:] if ln)}
    data = b""
    if "content-length" in got:
        data = await asyncio.wait_for(reader.readexactly(int(got["content-length"])), 5)
    writer.close()
    return int(lines[0].split()[1]), got, data


async def test_a_foreign_host_is_misdirected_and_the_probes_answer_any_host() -> None:
    async with console() as gw:
        port = gw.health.port
        for host in (f"127.0.0.1:{port}", f"localhost:{port}"):
            assert (await request(port, "GET", "/api/overview", {"Host": host}))[0] == 200
        code, _, body = await request(port, "POST", "/api/sim/wire/emcy",
                                      {"Host": "evil.example", "Content-Type": "application/json"}, b"{}")  # fmt: skip
        assert code == 421 and b"evil.example" in body
        assert gw.web.fault_routes.faults.state("wire")["emcy"] is None  # nothing injected
        for path in ("/healthz", "/livez", "/metrics"):
            assert (await request(port, "GET", path, {"Host": "evil.example"}))[0] == 200


async def test_with_a_token_the_operators_endpoints_need_it_and_the_overview_stays_open(
    tmp_path: Path,
) -> None:
    (tmp_path / "web.token").write_text(TOKEN + "\n")
    async with console(token_file=str(tmp_path / "web.token")) as gw:
        port = gw.health.port
        json_post = {"Content-Type": "application/json"}
        locked = [
            ("GET", "/api/journal", {}),
            ("GET", "/api/journal.csv", {}),
            ("GET", "/api/monitor/stream", {}),
            ("POST", "/api/read/wire/work_area_1_low_limit", json_post),
            ("POST", "/api/sim/wire/emcy", json_post),
        ]
        for method, path, headers in locked:
            code, _, _ = await request(port, method, path, headers, b"{}" if method == "POST" else b"")
            assert code == 401, path
        for path in ("/", "/api/overview", "/api/node/wire", "/events", "/monitor", "/api/sim"):
            assert (await request(port, "GET", path))[0] == 200, path
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        code, _, _ = await request(port, "POST", "/api/read/wire/work_area_1_low_limit", {**json_post, **bearer}, b"{}")
        assert code == 200
        code, headers, _ = await request(port, "POST", "/api/login", bearer)
        cookie = headers["set-cookie"].split(";")[0]
        code, headers, _ = await request(port, "GET", "/api/monitor/stream", {"Cookie": cookie})
        assert code == 200 and headers["content-type"] == "text/event-stream"
        code, _, _ = await request(port, "POST", "/api/sim/wire/emcy", {**json_post, "Cookie": cookie}, b"{}")
        assert code == 200


async def test_wrong_tokens_are_throttled_per_address_and_logged_with_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with console(token=TOKEN) as gw:
        port = gw.health.port
        with caplog.at_level(logging.WARNING, "gateway.web"):
            for i in range(FAILURES_LIMIT):
                wrong = {"Authorization": f"Bearer guess-{i:06d}"}
                assert (await request(port, "GET", "/api/journal", wrong, source="127.0.0.2"))[0] == 403
            code, headers, _ = await request(port, "GET", "/api/journal",
                                             {"Authorization": f"Bearer {TOKEN}"}, source="127.0.0.2")  # fmt: skip
        assert code == 429 and int(headers["retry-after"]) >= 60
        code, _, _ = await request(port, "GET", "/api/journal", {"Authorization": f"Bearer {TOKEN}"})
        assert code != 429  # another address is not held up by it
        assert any("127.0.0.2" in r.getMessage() and "wrong token" in r.getMessage() for r in caplog.records)


async def test_one_client_cannot_take_every_live_page() -> None:
    async with console() as gw:
        port = gw.health.port
        held = []
        try:
            for _ in range(LIVE_PER_CLIENT):
                reader, writer = await open_conn(port, "127.0.0.2")
                writer.write(f"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
                assert b" 200 " in await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
                held.append(writer)
            code, _, body = await request(port, "GET", "/api/stream", source="127.0.0.2")
            assert code == 503 and b"per client address" in body
            reader, writer = await open_conn(port, "127.0.0.3")  # another client gets one
            writer.write(f"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            assert b" 200 " in await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
            held.append(writer)
        finally:
            for w in held:
                w.close()


async def test_every_networks_monitor_and_recording_need_the_token() -> None:
    async with console(two_networks(token=TOKEN)) as gw:
        port = gw.health.port
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        for network in ("line1", "line2"):
            for path in (f"/api/monitor/stream?network={network}",
                         f"/api/monitor/record?network={network}&seconds=1"):  # fmt: skip
                assert (await request(port, "GET", path))[0] == 401, path
            code, headers, _ = await request(port, "HEAD", f"/api/monitor/stream?network={network}", bearer)
            assert code == 200 and headers["content-type"] == "text/event-stream"
        code, _, body = await request(port, "GET", "/api/monitor/stream?network=line3")
        assert code == 400 and b"line1, line2" in body  # a wrong name is told before the token
        code, headers, _ = await request(port, "GET", "/api/monitor/record?network=line2&seconds=1", bearer)
        assert code == 200 and "two-line2-bus-" in headers["content-disposition"]


async def test_a_clients_monitor_pages_are_counted_across_networks() -> None:
    async with console(two_networks()) as gw:
        port = gw.health.port
        held = []

        async def monitor_page(network: str, source: str) -> bytes:
            reader, writer = await open_conn(port, source)
            writer.write(f"GET /api/monitor/stream?network={network} HTTP/1.1\r\n"
                         f"Host: 127.0.0.1:{port}\r\n\r\n".encode())  # fmt: skip
            held.append(writer)
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
            if b" 200 " in head:  # the page is open once its hello came
                await asyncio.wait_for(reader.readuntil(b"event: hello"), 5)
            return head

        try:
            for _ in range(MONITOR_PER_CLIENT):
                assert b" 200 " in await monitor_page("line1", "127.0.0.2")
            code, _, body = await request(port, "GET", "/api/monitor/stream?network=line2", source="127.0.0.2")
            assert code == 503 and b"per client address" in body
            assert b" 200 " in await monitor_page("line2", "127.0.0.3")  # another client gets one
        finally:
            for w in held:
                w.close()


@pytest.mark.parametrize(
    "raw",
    ["Content-Length: \u00b2\r\n", "Content-Length: 2\r\nContent-Length: 2\r\n", "Content-Length: -1\r\n"],
    ids=["superscript-two", "twice", "negative"],
)
async def test_a_bad_content_length_is_a_400_without_a_traceback(
    raw: str, caplog: pytest.LogCaptureFixture
) -> None:
    async with console() as gw:
        with caplog.at_level(logging.WARNING):
            code, _, body = await request(gw.health.port, "POST", "/api/read/wire/x",
                                          {"Content-Type": "application/json"}, b"{}", raw_headers=raw)  # fmt: skip
        assert code == 400 and b"bad_request" in body
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
