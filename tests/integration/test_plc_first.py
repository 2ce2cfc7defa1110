"""The PLC first: no Zenoh query, console request or ASCII line runs ahead of a Modbus answer.

The gateway runs for real (simulated devices on a private virtual bus, Modbus over TCP, a Zenoh
peer over loopback, the console over HTTP), but the queries' worker is a controlled executor:
its thread is not started and the test turns it (``QueryWorker.step``), so what runs when is
decided by the test, never by timing."""

from __future__ import annotations

import asyncio
import json
import threading
import urllib.error
import urllib.request
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import zenoh
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
P = "canopen/test"


class Pending:
    """A get in flight: its replies arrive on a zenoh thread; ``ended`` when the get is over."""

    def __init__(self, session: zenoh.Session, selector: str, timeout_s: float = 10.0):
        self.replies: list[tuple[bool, Any]] = []
        self.ended = threading.Event()

        def on_reply(reply: zenoh.Reply) -> None:
            if reply.ok is not None:
                self.replies.append((True, json.loads(reply.ok.payload.to_bytes())))
            else:
                self.replies.append((False, json.loads(reply.err.payload.to_bytes())))

        handler = zenoh.handlers.Callback(on_reply, self.ended.set)
        session.get(selector, handler, timeout=timeout_s)


async def plc_read(port: int) -> Any:
    """A PLC's request: input registers 0..2 of unit 1, on a connection of its own."""
    plc = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=3)
    await plc.connect()
    try:
        return await plc.read_input_registers(0, count=3, device_id=1)
    finally:
        plc.close()


@asynccontextmanager
async def manual_worker(**sections: Any) -> AsyncIterator[tuple[Gateway, ZClient]]:
    """A started gateway whose queries' worker the test turns by hand, and a Zenoh peer."""
    cfg = make_config([WIRE], **sections)
    gw = gateway_of(cfg)
    assert gw.zenoh is not None
    gw.zenoh.queries.start = lambda threads: None  # type: ignore[method-assign]
    await gw.start()
    client = ZClient(cfg.zenoh.listen)
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        yield gw, client
    finally:
        client.close()
        await gw.stop()


async def test_a_queued_query_does_not_run_while_a_modbus_request_is_answered() -> None:
    async with manual_worker() as (gw, z):
        assert gw.zenoh is not None and gw.modbus is not None
        worker = gw.zenoh.queries.worker
        everything = Pending(z.session, f"{P}/**")
        snapshot = Pending(z.session, f"{P}/wire/snapshot")
        await wait_until(lambda: worker.depth == 2, 5, "both queries queued")

        rr = await plc_read(gw.modbus.port)
        assert not rr.isError() and len(rr.registers) == 3
        # the PLC was answered; the queries have not run
        assert worker.depth == 2 and worker.answered == 0
        assert everything.replies == [] and snapshot.replies == []

        while worker.step():  # the worker's turns, now
            pass
        await wait_until(lambda: everything.ended.is_set() and snapshot.ended.is_set(), 5, "gets")
        assert all(ok for ok, _ in everything.replies + snapshot.replies)
        assert [doc["node"] for _, doc in snapshot.replies] == ["wire"]
        assert len(everything.replies) > 2  # catalogue, state, snapshot, values
        assert (worker.answered, worker.depth) == (2, 0)


async def test_a_full_queue_answers_busy_with_a_retry_hint_and_loses_nothing_queued() -> None:
    async with manual_worker() as (gw, z):
        assert gw.zenoh is not None
        queries = gw.zenoh.queries
        queries.worker.queue_max = 1
        queued = Pending(z.session, f"{P}/wire/state")
        await wait_until(lambda: queries.worker.depth == 1, 5, "one query queued")

        refused = Pending(z.session, f"{P}/wire/snapshot")
        await wait_until(refused.ended.is_set, 5, "the refused get ended")
        [(ok, body)] = refused.replies
        assert not ok and body["error"] == "busy"
        assert body["key"] == f"{P}/wire/snapshot"
        assert body["retry_after_ms"] >= 50
        assert queries.busy == 1 and queries.worker.depth == 1

        while queries.worker.step():
            pass
        await wait_until(queued.ended.is_set, 5, "the queued get ended")
        [(ok, state)] = queued.replies
        assert ok and state["node"] == "wire"
        assert queries.answered == 1


async def test_a_command_goes_to_the_event_loop_and_is_answered_there() -> None:
    async with manual_worker() as (gw, z):
        assert gw.zenoh is not None
        worker = gw.zenoh.queries.worker
        upload = Pending(z.session, f"{P}/wire/sdo/1008/00")  # device name, by SDO
        await wait_until(lambda: worker.depth == 1, 5, "queued")
        assert worker.step()  # the worker hands it to the loop: its job ends at once
        assert worker.depth == 0
        await wait_until(upload.ended.is_set, 5, "the SDO answer")
        [(ok, body)] = upload.replies
        assert ok and body["object"] == "0x1008:00" and isinstance(body["value"], str)


async def test_metrics_count_queries_answered_refused_and_the_queue_depth() -> None:
    port = free_port()
    async with manual_worker(health={"host": "127.0.0.1", "port": port}) as (gw, z):
        assert gw.zenoh is not None
        worker = gw.zenoh.queries.worker
        worker.queue_max = 1
        first = Pending(z.session, f"{P}/wire/state")
        await wait_until(lambda: worker.depth == 1, 5, "queued")
        busy = Pending(z.session, f"{P}/wire/state")
        await wait_until(busy.ended.is_set, 5, "refused")

        def scrape() -> dict[str, float]:
            url = f"http://127.0.0.1:{port}/metrics"
            with urllib.request.urlopen(url, timeout=5) as r:
                text = r.read().decode()
            return {
                line.split()[0]: float(line.split()[1])
                for line in text.splitlines()
                if line.startswith("canopen_gateway_zenoh_quer")
            }

        m = await asyncio.to_thread(scrape)
        assert m["canopen_gateway_zenoh_query_queue_depth"] == 1
        assert m["canopen_gateway_zenoh_queries_busy_total"] == 1
        assert m["canopen_gateway_zenoh_queries_answered_total"] == 0
        while worker.step():
            pass
        await wait_until(first.ended.is_set, 5, "answered")
        m = await asyncio.to_thread(scrape)
        assert m["canopen_gateway_zenoh_query_queue_depth"] == 0
        assert m["canopen_gateway_zenoh_queries_answered_total"] == 1


async def test_console_and_ascii_clients_refused_a_turn_get_busy_and_the_plc_its_answer() -> None:
    """When too many console and ASCII requests wait for a turn on the event loop, a console
    API request is answered 503 busy with Retry-After and an ASCII line ERROR:102; the health
    probe and the PLC are not held up by turns at all."""
    port = free_port()
    async with manual_worker(
        health={"host": "127.0.0.1", "port": port}, ascii={"port": free_port()}
    ) as (gw, _z):
        assert gw.modbus is not None and gw.ascii is not None

        async def refused(bounded: bool = True) -> bool:
            gw.turns.refused += 1
            return False

        gw.turns.turn = refused  # type: ignore[method-assign]  # as when 256 already wait

        def get(path: str) -> tuple[int, dict[str, str], bytes]:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
                    return r.status, dict(r.headers), r.read()
            except urllib.error.HTTPError as exc:
                return exc.code, dict(exc.headers), exc.read()

        status, headers, body = await asyncio.to_thread(get, "/api/overview")
        assert status == 503 and headers["Retry-After"] == "1"
        assert json.loads(body)["error"] == "busy"
        status, _, _ = await asyncio.to_thread(get, "/healthz")
        assert status == 200

        reader, writer = await asyncio.open_connection("127.0.0.1", gw.ascii.port)
        writer.write(b"[7] 1 read 0x1008 0 vs\r\n")
        assert await asyncio.wait_for(reader.readuntil(b"\r\n"), 5) == b"[7] ERROR:102\r\n"
        writer.close()

        rr = await plc_read(gw.modbus.port)
        assert not rr.isError()
        assert gw.turns.refused == 2


async def test_a_gateway_built_with_freeze_gc_moves_what_it_built_out_of_the_collectors_reach() -> None:
    import gc

    cfg = make_config([WIRE], zenoh={"enabled": False}, modbus={"enabled": False})
    gw = gateway_of(cfg, freeze_gc=True)  # as ``canopen-gateway run`` builds it
    gc.unfreeze()
    try:
        await gw.start()
        assert gc.get_freeze_count() > 0
        await gw.stop()
    finally:
        gc.unfreeze()  # the test process's own objects back to the collector
