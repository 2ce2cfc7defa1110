"""The web console's first-hour endpoints over real HTTP on 127.0.0.1 (urllib), on a running
gateway: the register map as CSV (the same bytes as ``canopen-gateway registers --csv``), trend
samples with their quality, the event log with its filters, the read button's SDO upload (a
value; a device's SDO abort with its code and text, from python canopen's LocalNode; 429 past
the per-client budget), and the fault-injection API with its rule."""

from __future__ import annotations

import asyncio
import json
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import canopen
import pytest

from canopen_gateway.app import Gateway
from canopen_gateway.cli import main
from canopen_gateway.image import Quality
from tests.helpers import free_port, gateway_of, make_config, node_operational, wait_until
from tests.integration.test_never_lies import RawSgh10, started
from tests.integration.test_web_http import http

TOKEN = "fault-token-0042"


@asynccontextmanager
async def console(**sections: Any) -> AsyncIterator[tuple[Gateway, str]]:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        health={"port": free_port()},
        modbus={"enabled": False},
        zenoh={"enabled": False},
        **sections,
    )
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        yield gw, f"http://127.0.0.1:{gw.health.port}"
    finally:
        await gw.stop()


async def get_json(url: str) -> tuple[int, Any]:
    code, _, body = await http(url)
    return code, json.loads(body)


async def post_json(url: str, token: str | None = None) -> tuple[int, dict[str, str], Any]:
    code, headers, body = await http(url, {}, method="POST", token=token)
    return code, headers, json.loads(body)


async def test_the_register_map_downloads_as_the_csv_of_the_registers_command(
    capsys: pytest.CaptureFixture[str], tmp_path: Any
) -> None:
    async with console() as (gw, base):
        code, headers, body = await http(base + "/api/registers.csv")
        assert code == 200 and headers["Content-Type"] == "text/csv; charset=utf-8"
        assert headers["Content-Disposition"] == 'attachment; filename="test-registers.csv"'
        cfg_file = tmp_path / "gw.yaml"
        cfg_file.write_text(json.dumps(gw.cfg.model_dump(mode="json", exclude_none=True)))
        assert main(["registers", "--csv", "-c", str(cfg_file)]) == 0
        assert body.decode() == capsys.readouterr().out
        assert body.decode().splitlines()[0].startswith("unit_id,table,address")


async def test_trend_samples_carry_values_with_their_quality() -> None:
    async with console() as (gw, base):
        store = gw.web.trends
        await wait_until(lambda: store.seq >= 2, 5, "two trend samples")
        code, doc = await get_json(base + "/api/trend/wire")
        assert code == 200
        names = [s["name"] for s in doc["signals"]]
        assert "position" in names and "alarms" not in names  # a bit field is not plotted
        i = names.index("position")
        assert doc["signals"][i]["unit"] == "mm"
        assert len(doc["t"]) == len(doc["values"][i]) == len(doc["quality"][i]) >= 1
        assert doc["quality"][i][-1] == int(Quality.GOOD)
        assert isinstance(doc["values"][i][-1], float)
        # only what is new after a sequence number
        code, newer = await get_json(f"{base}/api/trend/wire?after={doc['seq']}")
        assert code == 200 and all(len(v) == len(newer["t"]) for v in newer["values"])
        assert (await http(base + "/api/trend/nope"))[0] == 404
        code, bad = await get_json(base + "/api/trend/wire?after=x")
        assert code == 400 and "after" in bad["message"]


async def test_the_event_log_has_state_changes_emcy_and_warnings_with_filters() -> None:
    async with console() as (gw, base):
        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.silence())
        await wait_until(lambda: not gw.image.nodes["wire"].health.alive, 5, "wire lost")
        gw.sim.runner.call(lambda now: sim.unsilence(now))
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire back")
        gw.sim.runner.call(lambda now: sim.raise_emcy(0x1000, 0x01, now=now))
        await wait_until(lambda: gw.image.nodes["wire"].health.emcy_count, 5, "EMCY received")
        import logging

        logging.getLogger("gateway.test").warning("a test warning about wire")
        code, doc = await get_json(base + "/api/events")
        assert code == 200
        kinds = {e["kind"] for e in doc["events"]}
        assert {"state", "emcy", "warning"} <= kinds
        lost = [e for e in doc["events"] if e["kind"] == "state" and "alive -> lost" in e["text"]]
        assert lost and lost[0]["node"] == "wire"
        emcy = next(e for e in doc["events"] if e["kind"] == "emcy")
        assert emcy["text"].startswith("wire: EMCY 0x1000")
        warning = next(e for e in doc["events"] if e["text"] == "a test warning about wire")
        assert warning["node"] == "wire" and warning["kind"] == "warning"
        code, only = await get_json(base + "/api/events?kind=emcy&node=wire")
        assert code == 200 and {e["kind"] for e in only["events"]} == {"emcy"}
        code, newer = await get_json(f"{base}/api/events?after={doc['seq']}&kind=emcy")
        assert code == 200 and newer["events"] == []
        code, bad = await get_json(base + "/api/events?kind=gossip")
        assert code == 400 and "gossip" in bad["message"]
        assert (await http(base + "/api/events?node=nope"))[0] == 404
        assert (await http(base + "/events"))[0] == 200


async def test_the_read_button_uploads_a_configuration_object_without_writes() -> None:
    async with console() as (gw, base):
        gw.sim.nodes["wire"].set(0x6401, 1, 1234)
        code, _, doc = await post_json(base + "/api/read/wire/work_area_1_low_limit")
        assert code == 200, doc
        assert doc["object"] == "0x6401:01" and doc["raw"] == 1234
        # TPDO values and unknown names are not configuration objects
        code, _, doc = await post_json(base + "/api/read/wire/position")
        assert code == 404 and "work_area_1_low_limit" in doc["message"]
        assert (await http(base + "/api/read/nope/x", {}, method="POST"))[0] == 404
        # a plain form post (no JSON content type) is refused: no cross-site reads
        def form_post() -> int:
            req = urllib.request.Request(
                base + "/api/read/wire/work_area_1_low_limit", data=b"x=1", method="POST"
            )
            req.add_header("Content-Type", "application/x-www-form-urlencoded")
            try:
                with urllib.request.urlopen(req, timeout=5) as r:
                    return r.status
            except urllib.error.HTTPError as e:
                return e.code

        assert await asyncio.to_thread(form_post) == 415
        assert (await http(base + "/api/read/wire/work_area_1_low_limit"))[0] == 405


async def test_reads_past_the_client_budget_answer_429_with_retry_after() -> None:
    async with console() as (gw, base):
        gw.web.read_budget.clock = lambda: 1000.0  # frozen: no refill during the test
        url = base + "/api/read/wire/work_area_1_low_limit"
        for _ in range(5):
            assert (await post_json(url))[0] == 200
        code, headers, doc = await post_json(url)
        assert code == 429 and doc["error"] == "rate_limited"
        assert headers["Retry-After"] == "1"
        assert "at most 2 SDO reads a second per client" in doc["message"]
        gw.web.read_budget.clock = lambda: 1000.5  # half a second later: one more read
        assert (await post_json(url))[0] == 200
        assert (await post_json(url))[0] == 429


async def test_a_device_abort_is_shown_with_its_code_and_text() -> None:
    cfg = make_config(
        [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        simulate={"nodes": []},
        master={"probe_at_start": False, "sync_period_ms": 0},
        health={"port": free_port()},
        modbus={"enabled": False},
        zenoh={"enabled": False},
    )
    dev = RawSgh10(cfg.can.channel)

    def refuse(index: int, subindex: int, od: Any) -> None:
        if index == 0x6401:
            raise canopen.sdo.exceptions.SdoAbortedError(0x08000022)

    dev.local.add_read_callback(refuse)
    gw = gateway_of(cfg)
    await gw.start()
    try:
        dev.boot()
        await started(gw, dev)
        dev.local.nmt.start_heartbeat(100)
        base = f"http://127.0.0.1:{gw.health.port}"
        code, _, doc = await post_json(base + "/api/read/wire/work_area_1_low_limit")
        assert code == 502
        assert doc["abort_code"] == "0x08000022"
        assert "present device state" in doc["abort_text"]
    finally:
        await gw.stop()
        dev.close()


async def test_faults_on_the_virtual_bus_need_no_token_and_act_on_the_simulated_node() -> None:
    async with console() as (gw, base):
        code, doc = await get_json(base + "/api/sim")
        assert code == 200 and doc["rule"] == "open"
        assert doc["nodes"]["wire"] == {"unplugged": False, "heartbeat": True, "emcy": None}
        code, _, doc = await post_json(base + "/api/sim/wire/unplug")
        assert code == 200 and doc["state"]["unplugged"] is True
        await wait_until(lambda: not gw.image.nodes["wire"].health.alive, 5, "wire lost")
        health = gw.image.nodes["wire"].health
        boots = health.boot_count
        code, _, doc = await post_json(base + "/api/sim/wire/plug")
        assert code == 200 and doc["state"]["unplugged"] is False
        await wait_until(lambda: health.boot_count == boots + 1, 5, "a boot-up")
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational again")
        code, events = await get_json(base + "/api/events?kind=warning&node=wire")
        texts = [e["text"] for e in events["events"]]
        assert "simulated fault: wire unplug (from web 127.0.0.1, the HTTP API)" in texts
        code, _, doc = await post_json(base + "/api/sim/wire/fly")
        assert code == 404 and "unplug" in doc["message"]
        code, _, doc = await post_json(base + "/api/sim/nope/unplug")
        assert code == 404 and "not simulated" in doc["message"]


async def test_faults_on_a_real_bus_need_writes_and_the_token() -> None:
    # the simulator on another interface stands for a simulated node on a real bus
    async with console(web={"writes": True, "token": TOKEN}) as (gw, base):
        gw.web.fault_routes.virtual_bus = False
        code, doc = await get_json(base + "/api/sim")
        assert doc["rule"] == "token"
        code, _, _ = await post_json(base + "/api/sim/wire/heartbeat-off")
        assert code == 401
        code, _, _ = await post_json(base + "/api/sim/wire/heartbeat-off", token="wrong-token-99")
        assert code == 403
        code, _, doc = await post_json(base + "/api/sim/wire/heartbeat-off", token=TOKEN)
        assert code == 200 and doc["state"]["heartbeat"] is False
        gw.web.fault_routes.writes = False
        code, doc = await get_json(base + "/api/sim")
        assert doc["rule"] == "none" and doc["nodes"] == {}
        code, _, _ = await http(base + "/api/sim/wire/heartbeat-on", {}, method="POST", token=TOKEN)
        assert code == 404


async def test_without_simulated_nodes_there_is_no_fault_api() -> None:
    async with console() as (gw, base):
        gw.web.fault_routes.faults = None
        code, doc = await get_json(base + "/api/sim")
        assert code == 200 and doc["rule"] == "none"
        assert (await http(base + "/api/sim/wire/unplug", {}, method="POST"))[0] == 404


async def test_the_fault_command_goes_through_the_running_gateway(
    capsys: pytest.CaptureFixture[str], tmp_path: Any
) -> None:
    async with console() as (gw, base):
        cfg_file = tmp_path / "gw.yaml"
        cfg_file.write_text(json.dumps(gw.cfg.model_dump(mode="json", exclude_none=True)))

        def cli(*argv: str) -> int:
            return main(["fault", "-c", str(cfg_file), *argv])

        assert await asyncio.to_thread(cli) == 0
        out = capsys.readouterr().out
        assert "wire: plugged, heartbeat on, no EMCY raised" in out
        assert await asyncio.to_thread(cli, "wire", "emcy") == 0
        assert "wire: emcy done" in capsys.readouterr().out
        await wait_until(lambda: gw.image.nodes["wire"].health.emcy_count, 5, "EMCY received")
        assert gw.web.fault_routes.faults.state("wire")["emcy"] is not None
        assert await asyncio.to_thread(cli, "wire", "fly") == 2
        assert "one of unplug, plug" in capsys.readouterr().err
        assert await asyncio.to_thread(cli, "other", "unplug") == 1
        assert "not simulated" in capsys.readouterr().err
    # the gateway is gone: one line saying so
    assert await asyncio.to_thread(cli, "wire", "unplug") == 1
    assert "no gateway answers at" in capsys.readouterr().err
