"""Several CAN networks in one gateway, as processes: a gateway process (``canopen-gateway run``)
masters two buses, each a socketcand server of its own (``tests/pair_bus.py``: it records every
frame with its sender and can unplug a member); the devices are simulated in this process, one
connection per bus (member ``dev``), with node id 1 on both buses.

* Both networks are booted by the one gateway: each its own master (node id 127 on each bus),
  its devices operational and served good on one Modbus server, /healthz naming both.
* CiA 309-3: ``[seq] net node r ...`` reaches node 1 of the net given (net 1 a POSI+, net 2 an
  SGH10: their device names differ); a net past the last is ERROR:106, a node not on the net
  ERROR:107.
* One bus unplugged (the gateway's connection to line2 closed and refused) while line1's node
  is polled every 10 ms: no poll misses, its quality never changes, and the POSI+ on line1,
  consuming its master's heartbeat (1016h), never reports a loss (EMCY 8130h); line2's process
  data answer 0x0A while its diagnostics (input register 0 on) are served; /healthz names
  line2; back on the bus, line2's values are good again.
* A hot-standby pair per network: two gateway processes on both buses; the active one loses
  its port to line2: the other takes line2 over, the first keeps line1 and, back on line2,
  stands by there; its Modbus refuses (0x06) a write to a node of the network it stands by on.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import urllib.request
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml
from pymodbus.client import ModbusTcpClient

from tests.helpers import (
    free_port,
    parse_checked_config,
    simulated_bus,
    stop_process,
    wait_ready,
    wait_until_sync,
)
from tests.pair_bus import PairBus

ROOT = Path(__file__).resolve().parents[2]
MASTER = 127
CONSUMER_MS = 1000  # POSI+ 1016h:01: consumer time of its master's heartbeat
EMCY_HEARTBEAT_LOST = 0x8130  # CiA 301 / POSI+ manual: life guard or heartbeat error
ENC_UNIT, WIRE_UNIT = 1, 101  # line1's node 1 (POSI+), line2's node 1 (SGH10)
QUALITY, PROCESS = 0, 100  # input registers: diagnostics quality, first process value


def network(name: str, bus: PairBus, member: str, node: dict[str, Any], **master: Any) -> dict[str, Any]:
    return {
        "name": name,
        "can": {**bus.can_section(member), "reopen_backoff_s": 0.2},
        "master": {"node_id": MASTER, "heartbeat_ms": 100, "heartbeat_timeout_multiple": 5,
                   "boot_timeout_s": 5, **master},  # fmt: skip
        "nodes": [node],
    }


def nodes() -> tuple[dict[str, Any], dict[str, Any]]:
    enc = {"name": "enc", "node_id": 1, "profile": "posi_plus", "heartbeat_ms": 200,
           # CiA 301 7.5.2.15: the encoder consumes its master's heartbeat
           "sdo": [{"object": "0x1016:01", "value": (MASTER << 16) | CONSUMER_MS}]}  # fmt: skip
    wire = {"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 200,
            "modbus": {"unit_id": WIRE_UNIT}}  # fmt: skip
    return enc, wire


def config(a: PairBus, b: PairBus, member: str, **sections: Any) -> dict[str, Any]:
    enc, wire = nodes()
    pairs = sections.pop("pairs", ({}, {}))
    return {
        "gateway": {"name": "nets"},
        "networks": [network("line1", a, member, enc, **pairs[0]),
                     network("line2", b, member, wire, **pairs[1])],  # fmt: skip
        "modbus": {"port": free_port()},
        "zenoh": {"enabled": False},
        **sections,
    }


@contextmanager
def devices(a: PairBus, b: PairBus) -> Iterator[Any]:
    """The devices of both networks simulated in this process, member ``dev`` of each bus."""
    sim = simulated_bus(parse_checked_config(config(a, b, "dev"), environ={}), ["enc", "wire"])
    sim.start()
    try:
        yield sim
    finally:
        sim.stop()


@contextmanager
def gateway(tmp: Path, raw: dict[str, Any], tag: str = "gw") -> Iterator[subprocess.Popen[str]]:
    path = tmp / f"{tag}.yaml"
    path.write_text(yaml.safe_dump(raw))
    proc = subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "run", "-c", str(path), "--log-level", "warning"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        wait_ready(proc)
        yield proc
    finally:
        stop_process(proc)


def healthz(port: int) -> dict[str, Any]:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=2) as r:
            return dict(json.load(r))
    except urllib.error.HTTPError as exc:  # 503 while not ready: the same document
        return dict(json.load(exc))


def good(client: ModbusTcpClient, unit: int) -> bool:
    r = client.read_input_registers(QUALITY, count=1, device_id=unit)
    return not r.isError() and r.registers[0] == 0


def ascii_lines(port: int, lines: list[str]) -> list[str]:
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall("".join(f"{line}\r\n" for line in lines).encode())
        s.shutdown(socket.SHUT_WR)
        data = b""
        while chunk := s.recv(4096):
            data += chunk
    return data.decode().splitlines()


class Poller(threading.Thread):
    """Line1's node polled every 10 ms (quality and position) until stopped: every answer
    kept, an exception or a quality other than good counted."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.client = ModbusTcpClient("127.0.0.1", port=port, timeout=2)
        self.stop_event = threading.Event()
        self.polls = 0
        self.bad: list[str] = []

    def run(self) -> None:
        assert self.client.connect()
        while not self.stop_event.wait(0.01):
            r = self.client.read_input_registers(QUALITY, count=1, device_id=ENC_UNIT)
            p = self.client.read_input_registers(PROCESS, count=2, device_id=ENC_UNIT)
            self.polls += 1
            if r.isError() or p.isError() or r.registers[0] != 0:
                self.bad.append(f"poll {self.polls}: {r} {p}")
        self.client.close()


@pytest.fixture
def buses() -> Iterator[tuple[PairBus, PairBus]]:
    with PairBus() as a, PairBus() as b:
        yield a, b


def test_one_gateway_masters_two_buses_and_one_bus_down_never_touches_the_other(
    tmp_path: Path, buses: tuple[PairBus, PairBus]
) -> None:
    a, b = buses
    health, ascii_port = free_port(), free_port()
    raw = config(a, b, "gw", health={"port": health},
                 ascii={"port": ascii_port, "host": "127.0.0.1"})  # fmt: skip
    with devices(a, b), gateway(tmp_path, raw):
        client = ModbusTcpClient("127.0.0.1", port=raw["modbus"]["port"], timeout=2)
        assert client.connect()
        wait_until_sync(lambda: good(client, ENC_UNIT) and good(client, WIRE_UNIT), 20, "both good")
        doc = healthz(health)
        assert doc["ready"] and {n: v["bus"]["state"] for n, v in doc["networks"].items()} == {
            "line1": "ok", "line2": "ok"}  # fmt: skip
        assert (doc["nodes"]["enc"]["network"], doc["nodes"]["wire"]["network"]) == ("line1", "line2")
        # each bus has its own master: the heartbeat of 127 on both
        assert a.sent_by("gw", 0x700 + MASTER) and b.sent_by("gw", 0x700 + MASTER)

        # CiA 309-3: the net chooses the bus
        assert ascii_lines(ascii_port, [
            "[1] 1 1 r 0x1008 0 vs", "[2] 2 1 r 0x1008 0 vs", "[3] 3 1 r 0x1008 0 vs",
            "[4] 1 2 r 0x1008 0 vs", "[5] set network 2", "[6] 1 r 0x1008 0 vs",
        ]) == ["[1] POSI+", "[2] SGH10", "[3] ERROR:106", "[4] ERROR:107", "[5] OK", "[6] SGH10"]  # fmt: skip

        poller = Poller(raw["modbus"]["port"])
        poller.start()
        wait_until_sync(lambda: poller.polls >= 10, 10, "polls before")
        mark = len(a.frames)
        b.unplug("gw")
        wait_until_sync(lambda: healthz(health)["networks"]["line2"]["bus"]["state"] == "down", 10,
                        "line2 down")  # fmt: skip
        doc = healthz(health)
        assert not doc["ready"] and any("network line2" in r for r in doc["reasons"])
        assert doc["networks"]["line1"]["bus"]["state"] == "ok"
        down = client.read_input_registers(PROCESS, count=2, device_id=WIRE_UNIT)
        assert down.isError() and down.exception_code == 0x0A  # gateway path unavailable
        diag = client.read_input_registers(QUALITY, count=16, device_id=WIRE_UNIT)
        assert not diag.isError()  # its diagnostics still served
        polls = poller.polls
        wait_until_sync(lambda: poller.polls >= polls + 50, 10, "polls while line2 is down")

        b.plug("gw")
        wait_until_sync(lambda: good(client, WIRE_UNIT), 20, "line2 good again")
        poller.stop_event.set()
        poller.join(5)
        client.close()
    assert poller.bad == []  # line1 answered every poll, good every time
    assert not [f for f in a.frames[mark:]  # its master's heartbeat never missed
                if f.cob_id == 0x081 and int.from_bytes(f.data[:2], "little") == EMCY_HEARTBEAT_LOST]  # fmt: skip


def test_a_pair_per_network_a_gateway_is_active_on_one_and_stands_by_on_the_other(
    tmp_path: Path, buses: tuple[PairBus, PairBus]
) -> None:
    """A masters both networks, B stands by on both; A loses its port to line2 (unplugged): B
    takes line2 over, A keeps line1; A back on line2 listens and stands by there (the member
    that masters the devices keeps the bus)."""
    a, b = buses
    ha, hb = free_port(), free_port()
    raw_a = config(a, b, "A", health={"port": ha}, pairs=(
        {"redundancy": {"node_id": 101, "priority": 0}}, {"redundancy": {"node_id": 101, "priority": 0}}))  # fmt: skip
    raw_b = config(a, b, "B", health={"port": hb}, pairs=(
        {"redundancy": {"node_id": 102, "priority": 1}}, {"redundancy": {"node_id": 102, "priority": 1}}))  # fmt: skip

    def roles(port: int) -> tuple[str, str]:
        nets = healthz(port)["networks"]
        return nets["line1"]["role"], nets["line2"]["role"]

    with ExitStack() as stack:
        stack.enter_context(gateway(tmp_path, raw_a, "A"))
        stack.enter_context(devices(a, b))  # once A listens: their boot-ups the first frames it hears
        wait_until_sync(lambda: roles(ha) == ("active", "active"), 20, "A active on both")
        stack.enter_context(gateway(tmp_path, raw_b, "B"))
        wait_until_sync(lambda: roles(hb) == ("standby", "standby"), 20, "B standby on both")
        b.unplug("A")  # A's port to line2 lost
        wait_until_sync(lambda: roles(hb) == ("standby", "active"), 20, "B takes line2 over")
        b.plug("A")
        wait_until_sync(lambda: roles(ha) == ("active", "standby"), 20, "A back, standby on line2")
        assert roles(hb) == ("standby", "active")
        client = ModbusTcpClient("127.0.0.1", port=raw_a["modbus"]["port"], timeout=2)
        assert client.connect()
        wait_until_sync(lambda: good(client, ENC_UNIT) and good(client, WIRE_UNIT), 20, "A serves both")
        # A masters line1 only: an NMT write (holding register 0) to line2's node is refused
        refused = client.write_register(0, 1, device_id=WIRE_UNIT)
        assert refused.isError() and refused.exception_code == 0x06  # server device busy
        done = client.write_register(0, 1, device_id=ENC_UNIT)  # NMT start to line1's node
        assert not done.isError()
        client.close()
