"""Store and forward with real processes: the gateway runs as its own process on a CAN bus
shared through python-can-remote; the test sends EMCY frames onto that bus as the device
would, kills the gateway with SIGKILL, and checks the journal and what Zenoh clients got.

* kill -9 during an EMCY flood: every event a subscriber received is in the journal (write
  ahead), with the same payload;
* a router (a router-mode eclipse-zenoh session) closed and opened again, with the gateway
  killed and started again in between: a client using docs/examples/backfill.py gets every
  event once and in order, and that is exactly what the journal holds."""

from __future__ import annotations

import importlib.util
import json
import os
import queue
import signal
import subprocess
import threading
from pathlib import Path
from typing import Any

import can
import pytest
import yaml
import zenoh

from canopen_gateway.journal import Journal
from tests.helpers import (
    free_port,
    gateway_process,
    start_can_remote,
    wait_can_remote,
    wait_ready,
    wait_until_sync,
)
from tests.zenoh_client import open_router, session_config

pytest.importorskip("can_remote")

P = "canopen/jp"
EMCY_WIRE = 0x81  # CiA 301: EMCY COB-ID 80h + node id 1
ROOT = Path(__file__).resolve().parents[2]


def emcy(code: int, register: int) -> can.Message:
    """An EMCY frame of node 1 (CiA 301 7.2.7.3: code, error register, 5 manufacturer bytes)."""
    data = code.to_bytes(2, "little") + bytes([register, 0, 0, 0, 0, 0])
    return can.Message(arbitration_id=EMCY_WIRE, data=data, is_extended_id=False)


class Bus:
    """A python-can-remote server process and this test's connection to it."""

    def __init__(self) -> None:
        self.port = free_port()
        self.server = start_can_remote(self.port, f"jp{self.port}")
        wait_can_remote(self.server, self.port)
        self.bus = can.Bus(interface="remote", channel=self.url)

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/"

    def events(self, n: int) -> None:
        for i in range(n):
            self.bus.send(emcy(0xFF05, 0x81) if i % 2 == 0 else emcy(0x0000, 0x00))

    def close(self) -> None:
        self.bus.shutdown()
        self.server.terminate()
        self.server.wait(10)


def config_file(tmp_path: Path, bus: Bus, zenoh_section: dict[str, Any]) -> Path:
    raw = {
        "gateway": {"name": "jp"},
        "can": {"interface": "remote", "channel": bus.url},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"enabled": False},
        "zenoh": {"prefix": P, **zenoh_section},
        "journal": {"path": str(tmp_path / "journal")},
    }
    path = tmp_path / "gw.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def kill(proc: subprocess.Popen[str]) -> None:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)


def journaled(tmp_path: Path, key: str) -> list[dict[str, Any]]:
    return [json.loads(r.payload) for r in Journal(tmp_path / "journal").read([key])]


def test_kill_9_during_an_emcy_flood_leaves_every_received_event_in_the_journal(tmp_path):
    bus = Bus()
    listen = f"tcp/127.0.0.1:{free_port()}"
    gw = gateway_process(config_file(tmp_path, bus, {"listen": [listen]}))
    client = None
    try:
        wait_ready(gw)
        client = zenoh.open(session_config("peer", connect=[listen]))
        got: queue.Queue[bytes] = queue.Queue()
        sub = client.declare_subscriber(f"{P}/wire/emcy", lambda s: got.put(s.payload.to_bytes()))
        bus.events(2)  # the subscriber is matched once these two arrive
        wait_until_sync(lambda: got.qsize() >= 2, 20, "the first EMCY events")
        flood = threading.Thread(target=bus.events, args=(4000,), daemon=True)
        flood.start()
        wait_until_sync(lambda: got.qsize() >= 300, 30, "300 EMCY events received")
        kill(gw)  # in the middle of the flood
        flood.join(30)
        sub.undeclare()
        received = []
        while not got.empty():
            received.append(json.loads(got.get_nowait()))
        in_journal = {e["seq"]: e for e in journaled(tmp_path, f"{P}/wire/emcy")}
        assert len(received) >= 300
        missing = [e["seq"] for e in received if in_journal.get(e["seq"]) != e]
        assert missing == []
        assert [e["seq"] for e in received] == sorted(e["seq"] for e in received)
    finally:
        if gw.poll() is None:
            kill(gw)
        if client is not None:
            client.close()
        bus.close()


def gateway_seen(client: zenoh.Session) -> bool:
    replies = client.liveliness().get(f"{P}/alive/_gateway", timeout=1.0)
    return any(r.ok is not None for r in replies)


def _example() -> Any:
    spec = importlib.util.spec_from_file_location("backfill", ROOT / "docs/examples/backfill.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_router_outage_and_gateway_kill_every_event_once_and_in_order(tmp_path):
    backfilled = _example().backfilled
    bus = Bus()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    cfg = config_file(tmp_path, bus, {"mode": "peer", "listen": [], "connect": [endpoint]})
    gw = gateway_process(cfg)
    client = zenoh.open(session_config("client", connect=[endpoint]))
    key = f"{P}/wire/emcy"
    delivered: list[int] = []

    def consume() -> None:
        for seq, _body in backfilled(client, key):
            delivered.append(seq)

    reader = threading.Thread(target=consume, daemon=True)
    try:
        wait_ready(gw)
        reader.start()
        bus.events(2)  # before the subscriber is matched these may go unseen: backfilled
        wait_until_sync(lambda: len(delivered) >= 2, 20, "2 events delivered")
        bus.events(20)
        wait_until_sync(lambda: len(delivered) >= 22, 20, "22 events delivered")

        router.close()  # the cloud link is down: events go on into the journal
        bus.events(30)
        wait_until_sync(lambda: len(journaled(tmp_path, key)) >= 52, 20, "52 events journaled")
        kill(gw)
        gw = gateway_process(cfg)
        wait_ready(gw)
        bus.events(10)  # journaled by the new gateway, with seq going on
        wait_until_sync(lambda: len(journaled(tmp_path, key)) >= 62, 20, "62 events journaled")

        router = open_router(endpoint)  # the client and the gateway reconnect by themselves
        wait_until_sync(lambda: gateway_seen(client), 30, "the gateway's token through the router")
        bus.events(4)  # a live sample shows the gap, the journal fills it
        wait_until_sync(lambda: len(delivered) >= 66, 60, f"66 events delivered: {delivered}")
        assert delivered == list(range(1, 67))
        assert [e["seq"] for e in journaled(tmp_path, key)] == list(range(1, 67))
    finally:
        if gw.poll() is None:
            kill(gw)
        client.close()
        router.close()
        bus.close()
