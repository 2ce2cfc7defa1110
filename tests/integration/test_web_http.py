"""The web console's HTTP endpoints on a running gateway with simulated devices, over real HTTP
on 127.0.0.1 (urllib): pages, API, server-sent events, and the commissioning API (absent
without ``web.writes``, refused without the token, 400 with words for bad input)."""

from __future__ import annotations

import asyncio
import json
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import can
import pytest

from canopen_gateway.app import Gateway
from canopen_gateway.config import ConfigError, parse_config
from tests.helpers import free_port, gateway_of, make_config, node_operational, wait_until

TOKEN = "plant-floor-token-42"
TIMEOUT_S = 5.0


@asynccontextmanager
async def console(writes: bool, northbound: bool = False) -> AsyncIterator[tuple[Gateway, str]]:
    web = {"writes": True, "token": TOKEN} if writes else {}
    off = {} if northbound else {"modbus": {"enabled": False}, "zenoh": {"enabled": False}}
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        health={"port": free_port()},
        web=web,
        **off,
    )
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        yield gw, f"http://127.0.0.1:{gw.health.port}"
    finally:
        await gw.stop()


async def http(
    url: str,
    body: Any = None,
    *,
    token: str | None = None,
    method: str | None = None,
    raw: bytes | None = None,
) -> tuple[int, dict[str, str], bytes]:
    def go() -> tuple[int, dict[str, str], bytes]:
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        req = urllib.request.Request(url, data=data, method=method)
        if token is not None:
            req.add_header("Authorization", f"Bearer {token}")
        if data is not None:
            req.add_header("Content-Type", "application/json")
        try:
            with urllib.request.urlopen(req, timeout=TIMEOUT_S) as r:
                return r.status, dict(r.headers), r.read()
        except urllib.error.HTTPError as e:
            return e.code, dict(e.headers), e.read()

    return await asyncio.wait_for(asyncio.to_thread(go), TIMEOUT_S + 1)


async def post(base: str, op: str, body: Any, token: str | None = TOKEN) -> tuple[int, dict]:
    code, _, data = await http(f"{base}/api/commission/{op}", body, token=token, method="POST")
    return code, json.loads(data)


async def test_pages_static_files_and_api_are_served_on_the_health_port() -> None:
    async with console(writes=False, northbound=True) as (gw, base):
        code, headers, body = await http(base + "/")
        assert code == 200 and headers["Content-Type"].startswith("text/html")
        assert b"/static/console.js" in body
        assert "default-src 'self'" in headers["Content-Security-Policy"]  # no CDN possible
        assert (await http(base + "/static/console.css"))[0] == 200
        assert (await http(base + "/node/wire"))[0] == 200
        assert (await http(base + "/healthz"))[0] == 200  # the probes are still there
        code, _, body = await http(base + "/api/overview")
        doc = json.loads(body)
        assert code == 200 and doc["writes"] is False
        assert doc["overview"]["can"]["state"] == "ok"
        (row,) = doc["nodes"]
        assert row["name"] == "wire" and row["presence"] == "alive"
        assert row["quality"] == "good" and row["nmt_state"] == "operational"
        assert row["supervision_timing"] == "heartbeat 100 ms, lost after 300 ms"
        code, _, body = await http(base + "/api/node/wire")
        detail = json.loads(body)
        position = next(s for s in detail["signals"] if s["name"] == "position")
        assert position["modbus"] == "IR 100-101 @ unit 1"
        assert position["zenoh"] == ["canopen/test/wire/value/position"]
        assert position["unit"] == "mm"
        assert detail["values"]["position"]["quality"] == "good"
        assert any(r["signal"] == "position" for r in detail["registers"])
        assert doc["overview"]["modbus"]["serving"] is True
        assert doc["overview"]["zenoh"]["up"] is True


async def test_without_modbus_and_zenoh_the_node_page_says_they_are_off() -> None:
    async with console(writes=False) as (_, base):
        detail = json.loads((await http(base + "/api/node/wire"))[2])
        position = next(s for s in detail["signals"] if s["name"] == "position")
        assert position["modbus"] == "Modbus off" and position["zenoh"] == ["Zenoh off"]
        assert detail["registers"] == []
        assert (await http(base + "/api/stream", method="HEAD"))[0] == 200


async def test_unknown_nodes_and_paths_answer_404() -> None:
    async with console(writes=False) as (_, base):
        code, _, body = await http(base + "/api/node/nope")
        assert code == 404 and "nope" in json.loads(body)["message"]
        # a browser at a node page of no node gets a page (404), not the API's JSON
        code, headers, body = await http(base + "/node/nope")
        assert code == 404 and headers["Content-Type"].startswith("text/html")
        assert b"<h1>Not found</h1>" in body and b'data-page="notfound"' in body
        assert (await http(base + "/static/../config.py"))[0] == 404
        assert (await http(base + "/static/missing.js"))[0] == 404
        assert (await http(base + "/api/stream?node=nope"))[0] == 404
        assert (await http(base + "/api/overview", method="DELETE"))[0] == 405


async def test_the_stream_sends_the_nodes_table_and_then_live_values_of_a_node() -> None:
    async with console(writes=False) as (_, base):
        reader, writer = await asyncio.open_connection("127.0.0.1", int(base.rsplit(":", 1)[1]))
        writer.write(b"GET /api/stream?node=wire HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        await writer.drain()
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), TIMEOUT_S)
        assert b"200 OK" in head and b"text/event-stream" in head
        seqs = []
        while len(seqs) < 3:
            line = await asyncio.wait_for(reader.readline(), TIMEOUT_S)
            if line.startswith(b"data:") and b'"position"' in line:
                doc = json.loads(line[5:])
                if "seq" in doc.get("position", {}):
                    seqs.append(doc["position"]["seq"])
        assert seqs == sorted(seqs) and seqs[0] < seqs[-1]  # the value moves
        writer.close()


async def test_commissioning_is_absent_when_writes_are_off() -> None:
    async with console(writes=False) as (_, base):
        assert (await http(base + "/commissioning"))[0] == 404
        for op, token in (("sdo-read", TOKEN), ("login", "anything"), ("nmt", None)):
            code, _, body = await http(
                f"{base}/api/commission/{op}", {"node": "wire"}, token=token, method="POST"
            )
            assert code == 404
            assert json.loads(body) == {"error": "not_found", "message": "not found"}


async def test_commissioning_refuses_without_the_token_401_and_with_a_wrong_one_403() -> None:
    async with console(writes=True) as (_, base):
        assert (await http(base + "/commissioning"))[0] == 200
        code, headers, body = await http(
            base + "/api/commission/sdo-read", {"node": "wire", "object": "0x1018:01"}, method="POST"
        )
        assert code == 401 and headers["WWW-Authenticate"].startswith("Bearer")
        code, doc = await post(base, "sdo-read", {"node": "wire", "object": "0x1018:01"}, "wrong")
        assert code == 403 and doc["error"] == "forbidden"
        code, doc = await post(base, "login", {}, TOKEN)
        assert code == 200 and doc["ok"] is True
        code, _, _ = await http(base + "/api/commission/login", token=TOKEN)  # GET
        assert code == 405


async def test_sdo_read_write_and_abort_texts_through_the_command_service() -> None:
    async with console(writes=True) as (gw, base):
        code, doc = await post(base, "sdo-read", {"node": "wire", "object": "0x1018:01"})
        assert code == 200 and doc["value"] == 0x195  # SGH10 vendor id
        code, doc = await post(
            base, "sdo-write", {"node": "wire", "object": "0x6401:01", "value": 1234}
        )
        assert code == 200, doc
        sim = gw.sim.nodes["wire"]
        assert sim.get(0x6401, 1) == 1234  # reached the device
        code, doc = await post(base, "sdo-read", {"node": "wire", "object": "0x1018:09"})
        assert code == 502
        assert doc["abort_code"] == "0x06090011" and doc["abort_text"] == "Sub-index does not exist"
        code, doc = await post(
            base, "sdo-write", {"node": "wire", "object": "0x1018:01", "value": 1, "type": "uint32"}
        )
        assert code == 502 and doc["abort_text"] == "Attempt to write a read only object"


async def test_bad_input_gets_400_with_a_message_and_nothing_crashes() -> None:
    async with console(writes=True) as (_, base):
        cases = [
            ("sdo-read", b"{not json", "not JSON"),
            ("sdo-read", b"[1, 2]", "JSON object"),
            ("sdo-read", b'{"node": "wire"}', "object"),
            ("sdo-read", b'{"node": "wire", "object": "banana"}', "object address"),
            ("sdo-read", b'{"node": "wire", "object": "0x1018:01", "type": "u33"}', "type"),
            ("sdo-write", b'{"node": "wire", "object": "0x6401:01"}', "value"),
            ("sdo-write", b'{"node": "wire", "object": "0x6401:01", "value": [1]}', "value"),
            ("sdo-write", b'{"node": "wire", "object": "0x6401:01", "value": "x", "type": "bytes"}', "hex"),
            ("nmt", b'{"node": "wire", "command": "explode"}', "start"),
            ("set", b'{"node": "wire", "signal": "position", "value": 1}', "read-only"),
            ("set", b'{"node": "wire", "signal": "nope", "value": 1}', "no signal"),
            ("set", b'{"node": "wire", "signal": "calibration_value"}', "value"),
            ("lss-inquire", b'{"address": "1:2"}', "VENDOR:PRODUCT"),
        ]
        for op, raw, words in cases:
            code, _, body = await http(
                f"{base}/api/commission/{op}", raw=raw, token=TOKEN, method="POST"
            )
            doc = json.loads(body)
            assert code == 400, (op, raw, code, doc)
            assert words.lower() in doc["message"].lower(), (op, raw, doc)
        code, doc = await post(base, "sdo-read", {"node": "ghost", "object": "0x1000:00"})
        assert code == 404 and "wire" in doc["message"]  # names the configured nodes
        code, doc = await post(base, "frobnicate", {})
        assert code == 404 and "sdo-read" in doc["message"]
        code, _, body = await http(
            f"{base}/api/commission/sdo-read", raw=b"x" * 70_000, token=TOKEN, method="POST"
        )
        assert code == 413  # the server's own refusals under /api/ are JSON too
        assert json.loads(body) == {"error": "too_large", "message": "body larger than 65536 bytes"}
        assert (await http(base + "/livez"))[0] == 200
        code, doc = await post(base, "sdo-read", {"node": "wire", "object": "0x1000:00"})
        assert code == 200  # still serving


async def test_nmt_and_set_point_writes_go_through_the_command_service() -> None:
    async with console(writes=True) as (gw, base):
        code, doc = await post(base, "nmt", {"node": "wire", "command": "preop"})
        assert code == 200
        await wait_until(lambda: gw.sim.nodes["wire"].nmt_state == 0x7F, 3, "wire pre-operational")
        code, doc = await post(base, "nmt", {"node": "all", "command": "start"})
        assert code == 200
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational again")
        # an SDO-backed writable signal, engineering units (mm, scale 0.1) -> raw
        code, doc = await post(base, "set", {"node": "wire", "signal": "calibration_value", "value": 12.5})
        assert code == 200 and doc["raw"] == 125, doc
        assert gw.sim.nodes["wire"].get(0x6010, 1) == 125


async def test_lss_inquiry_from_the_running_gateway_goes_through_the_masters_connection(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    async with console(writes=True) as (gw, base):

        def no_second_connection(*args: Any, **kwargs: Any) -> None:
            raise AssertionError("a second can.Bus was opened while the gateway runs")

        monkeypatch.setattr(can, "Bus", no_second_connection)
        code, doc = await post(base, "lss-inquire", {})
        assert code == 200, doc
        assert doc["vendor_id"] == "0x00000195" and doc["node_id"] == 1
        assert gw.master.lss.machine.mode == "waiting", "the slaves are switched back to waiting"


def test_writes_without_a_token_is_a_config_error_naming_the_key_and_the_variable() -> None:
    with pytest.raises(ConfigError) as err:
        parse_config({"web": {"writes": True}}, "plant.yaml", environ={})
    assert "plant.yaml: web: writes: true needs a token" in str(err.value)
    assert "CANOPEN_GATEWAY__WEB__TOKEN" in str(err.value)
    cfg = parse_config(
        {"web": {"writes": True}}, "plant.yaml", environ={"CANOPEN_GATEWAY__WEB__TOKEN": TOKEN}
    )
    assert cfg.web.token == TOKEN
