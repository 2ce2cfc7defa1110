"""A hot-standby pair as separate processes: two gateways (``canopen-gateway run``, one config
file, each gateway's own id, priority and Modbus port from the environment as in a container),
the devices simulated in a third process (``canopen-gateway simulate``), all on one
python-can-remote bus; the test observes the bus from a fourth connection and talks Modbus to
both gateways with a pymodbus client.

Who sent a frame: a bus cannot say, so each gateway process runs with a spy on its driver's
``send`` that appends every frame it queues to a file (one ``write`` per frame: what the
process sent before a SIGKILL is on the file). Roles come from the gateways' log lines
(``pair: negotiating -> active``).

The scenario (docs/redundancy.md): A (priority 0) starts and configures the devices; B
(priority 1) joins as standby and sends only its own heartbeat and its detection request; both
serve node 1 good; a write through A is B's output too. A is killed (SIGKILL): B takes over,
its Modbus answers node 1 good through it, a write through B keeps the set point A had sent in
the same RPDO. A restarts and stays standby. B is frozen (SIGSTOP): A takes over; B thawed
stands by again, one sender of the logical heartbeat. Over the run no NMT command, no device
leaves OPERATIONAL, no boot-up, and the POSI+ encoder, consuming the logical heartbeat (1016h),
never reports its loss (EMCY 8130h). Timings are the bench's (``python -m bench pair``).
"""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import can
import pytest
import yaml
from pymodbus.client import ModbusTcpClient

from canopen_gateway.config import load_config
from canopen_gateway.northbound.regmap import Point, build_register_map
from tests.helpers import (
    can_remote_server,
    free_port,
    stop_process,
    wait_ready,
    wait_until_sync,
    with_nodes,
)

pytest.importorskip("can_remote")

ROOT = Path(__file__).resolve().parents[2]
LOGICAL, A_ID, B_ID = 100, 101, 102
HB_MS = 100
CONSUMER_MS = 1000  # the encoder's 1016h consumer time of the logical master (see test_pair_localnode)
COB_NMT, COB_SYNC, COB_EMCY, COB_HB, COB_RSDO = 0x000, 0x080, 0x080, 0x700, 0x600  # CiA 301 7.3.5
COB_MASTER_REQUEST = 0x73  # CiA 302-2: active master request (detection)
EMCY_HEARTBEAT_LOST = 0x8130  # CiA 301 / POSI+ manual 002 ch. 4: life guard or heartbeat error
NODES = {"wire": 1, "display": 2, "enc": 3}

#: ``python -c SPY FILE run -c ...``: the gateway's command line with every frame its driver
#: queues appended to FILE as ``<time.time()> <COB-ID hex> <data hex>``
SPY = """
import os, sys, time
from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.cli import main
fd = os.open(sys.argv[1], os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
real = BusDriver.send
def send(self, cob_id, data=b"", rtr=False, dlc=None):
    os.write(fd, b"%.6f %03X %s\\n" % (time.time(), cob_id, bytes(data).hex().encode()))
    return real(self, cob_id, data, rtr, dlc)
BusDriver.send = send
sys.exit(main(sys.argv[2:]))
"""


class Observer(can.Listener):
    """Every frame on the bus with its bus timestamp, as a connection of its own hears it."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, int, bytes]] = []
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        with self.lock:
            self.frames.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))

    def since(self, mark: int) -> list[tuple[float, int, bytes]]:
        with self.lock:
            return self.frames[mark:]

    def mark(self) -> int:
        with self.lock:
            return len(self.frames)

    def count(self, cob_id: int, mark: int = 0) -> int:
        return sum(1 for _, c, _ in self.since(mark) if c == cob_id)


class Gw:
    """One gateway process of the pair, spied (its frames) and logged (its stderr)."""

    def __init__(self, tmp: Path, tag: str, cfg: Path, node_id: int, priority: int) -> None:
        self.spy, self.log = tmp / f"{tag}.frames", tmp / f"{tag}.log"
        self.modbus_port = free_port()
        env = {
            **os.environ,
            "CANOPEN_GATEWAY__MASTER__REDUNDANCY__NODE_ID": str(node_id),
            "CANOPEN_GATEWAY__MASTER__REDUNDANCY__PRIORITY": str(priority),
            "CANOPEN_GATEWAY__MODBUS__PORT": str(self.modbus_port),
        }
        with self.log.open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", SPY, str(self.spy), "run", "-c", str(cfg), "--no-simulate",
                 "--log-level", "info"],  # fmt: skip
                cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=err, text=True,
            )  # fmt: skip
        self.client: ModbusTcpClient | None = None

    def ready(self) -> Gw:
        wait_ready(self.proc)
        self.client = ModbusTcpClient("127.0.0.1", port=self.modbus_port, timeout=2)
        assert self.client.connect()
        return self

    def sent(self, since_s: float = 0.0) -> list[tuple[float, int, bytes]]:
        if not self.spy.exists():
            return []
        out = []
        for line in self.spy.read_text().splitlines():
            t, cob, data = (line.split(" ") + [""])[:3]
            if float(t) >= since_s:
                out.append((float(t), int(cob, 16), bytes.fromhex(data)))
        return out

    def cobs(self, since_s: float = 0.0) -> list[int]:
        return [c for _, c, _ in self.sent(since_s)]

    def said(self, text: str) -> int:
        return self.log.read_text().count(text)

    def stop(self) -> None:
        if self.client is not None:
            self.client.close()
        stop_process(self.proc, thaw=True)


def write_config(tmp: Path, port: int) -> Path:
    raw: dict[str, Any] = {
        "gateway": {"name": "pair"},
        "can": {"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"},
        "master": {
            "node_id": LOGICAL,
            "heartbeat_ms": HB_MS,
            "sync_period_ms": 100,
            # the devices' heartbeats 200 ms, lost after 1 s: a relay process starved for a few
            # hundred ms by a gateway process starting beside it does not lose every node
            "heartbeat_timeout_multiple": 5,
            "redundancy": {"node_id": A_ID, "priority": 0},  # B's from the environment
        },
        "nodes": [
            {"name": "wire", "node_id": NODES["wire"], "profile": "sgh10", "heartbeat_ms": 200},
            {"name": "display", "node_id": NODES["display"], "profile": "ap05", "heartbeat_ms": 200},
            {"name": "enc", "node_id": NODES["enc"], "profile": "posi_plus", "heartbeat_ms": 200,
             # CiA 301 7.5.2.15: consumer of the logical master's heartbeat
             "sdo": [{"object": "0x1016:01", "value": (LOGICAL << 16) | CONSUMER_MS}]},
        ],  # fmt: skip
        "modbus": {"port": 0},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": "all"},
    }
    path = tmp / "pair.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@contextmanager
def started(argv: list[str], **kw: Any) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen(argv, cwd=ROOT, text=True, **kw)
    try:
        yield proc
    finally:
        stop_process(proc)


def point(cfg: Path, node: str, name: str) -> Point:
    rm = build_register_map(*with_nodes(load_config(cfg, environ={})))
    return next(p for p in rm.node_points(node) if p.name == name)


def quality_good(gw: Gw, quality: Point) -> bool:
    assert gw.client is not None
    r = gw.client.read_input_registers(quality.address, count=1, device_id=quality.unit)
    return not r.isError() and r.registers[0] == 0


def read_good(gw: Gw, quality: Point, position: Point) -> int | None:
    """Node 1's position as the gateway serves it, or None when it is not served good."""
    assert gw.client is not None
    q = gw.client.read_input_registers(quality.address, count=1, device_id=quality.unit)
    v = gw.client.read_input_registers(position.address, count=2, device_id=position.unit)
    if q.isError() or v.isError() or q.registers[0] != 0:
        return None
    return int(struct.unpack(">i", struct.pack(">HH", *v.registers))[0])


def hr_write(gw: Gw, p: Point, value: int) -> None:
    assert gw.client is not None
    words = list(struct.unpack(">HH", struct.pack(">i", value))) if p.count == 2 else [value]
    r = gw.client.write_registers(p.address, words, device_id=p.unit)
    assert not r.isError(), r


def hr_read(gw: Gw, p: Point) -> int | None:
    assert gw.client is not None
    r = gw.client.read_holding_registers(p.address, count=p.count, device_id=p.unit)
    if r.isError():
        return None
    return int(struct.unpack(">i", struct.pack(">HH", *r.registers))[0]) if p.count == 2 else r.registers[0]


class Poller(threading.Thread):
    """Reads node 1 from one gateway every 50 ms and keeps every answer (None: not good)."""

    def __init__(self, gw: Gw, quality: Point, position: Point) -> None:
        super().__init__(daemon=True)
        self.gw, self.quality, self.position = gw, quality, position
        self.answers: list[int | None] = []
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.wait(0.05):
            self.answers.append(read_good(self.gw, self.quality, self.position))


def test_a_pair_of_processes_survives_kill_restart_and_freeze(tmp_path: Path) -> None:
    port = free_port()
    cfg = write_config(tmp_path, port)
    quality, position = point(cfg, "wire", "quality"), point(cfg, "wire", "position")
    set_point2, control = point(cfg, "display", "set_point2"), point(cfg, "display", "control_word")
    logical = COB_HB + LOGICAL
    with ExitStack() as stack:
        stack.enter_context(can_remote_server(port, f"pair{port}"))
        bus = can.Bus(interface="remote", channel=f"ws://127.0.0.1:{port}/")
        stack.callback(bus.shutdown)
        seen = Observer()
        stack.callback(can.Notifier(bus, [seen]).stop)
        # A alone configures the devices, which power on once it listens (their boot-ups the
        # first frames it hears: on a bus silent from its start it waits 2 s before a claim)
        a = Gw(tmp_path, "a", cfg, A_ID, 0)
        stack.callback(lambda: a.stop())
        a.ready()
        sim = stack.enter_context(
            started([sys.executable, "-m", "canopen_gateway", "simulate", "-c", str(cfg)],
                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)  # fmt: skip
        )
        assert sim.stdout is not None and "simulating" in sim.stdout.readline()
        wait_until_sync(lambda: a.said("pair: negotiating -> active"), 15, "A active")
        for name, node_id in NODES.items():
            q = point(cfg, name, "quality")
            wait_until_sync(lambda q=q: quality_good(a, q), 20, f"A serves {name} (id {node_id}) good")
        configured = seen.mark()

        # B joins as standby: its own heartbeat and its detection request, nothing else
        b_started_s = time.time()
        b = Gw(tmp_path, "b", cfg, B_ID, 1)
        stack.callback(lambda: b.stop())
        b.ready()
        wait_until_sync(lambda: b.said("pair: listening -> standby"), 10, "B standby")
        wait_until_sync(lambda: read_good(b, quality, position) is not None, 10, "B serves node 1 good")
        assert read_good(a, quality, position) is not None
        hr_write(a, set_point2, 4321)
        wait_until_sync(lambda: hr_read(b, set_point2) == 4321, 10, "A's write is B's output")
        wait_until_sync(lambda: b.cobs().count(COB_HB + B_ID) >= 5, 10, "B's own heartbeats")
        assert set(b.cobs()) <= {COB_HB + B_ID, COB_MASTER_REQUEST}, sorted(set(b.cobs()))
        assert b.cobs().count(COB_MASTER_REQUEST) <= 3
        assert not [c for c in a.cobs(b_started_s) if c == COB_NMT or COB_RSDO < c <= COB_RSDO + 127]

        # A is killed: B takes over; its Modbus answers node 1 good throughout
        poller = Poller(b, quality, position)
        poller.start()
        wait_until_sync(lambda: len(poller.answers) >= 5, 10, "B polled before the kill")
        killed_s = time.time()
        os.kill(a.proc.pid, signal.SIGKILL)
        a.proc.wait()
        wait_until_sync(lambda: b.said("pair: negotiating -> active"), 10, "B active")
        wait_until_sync(lambda: b.cobs(killed_s).count(logical) >= 10, 10, "B's logical heartbeats")
        poller.stop.set()
        poller.join()
        assert len(poller.answers) >= 10
        assert None not in poller.answers, poller.answers
        # a write through B goes out in RPDO2 with the set point A had sent
        write_s = time.time()
        hr_write(b, control, 0)
        wait_until_sync(lambda: 0x300 + NODES["display"] in b.cobs(write_s), 10, "B's RPDO2")
        rpdo2 = [d for _, c, d in b.sent(killed_s) if c == 0x300 + NODES["display"]]
        assert rpdo2 and all(struct.unpack_from("<i", d)[0] == 4321 for d in rpdo2)

        # A restarts and stays standby
        a = Gw(tmp_path, "a2", cfg, A_ID, 0)
        a.ready()
        wait_until_sync(lambda: a.said("pair: listening -> standby"), 10, "A standby again")
        restarted = seen.mark()
        wait_until_sync(lambda: seen.count(logical, restarted) >= 10, 10, "the logical heartbeat goes on")
        assert set(a.cobs()) <= {COB_HB + A_ID, COB_MASTER_REQUEST}, sorted(set(a.cobs()))
        assert a.said("-> active") == 0 and b.said("active ->") == 0

        # B frozen: A takes over; B thawed stands by, one sender of the logical heartbeat
        os.kill(b.proc.pid, signal.SIGSTOP)
        frozen_s = time.time()
        wait_until_sync(lambda: a.said("pair: negotiating -> active"), 10, "A takes over from frozen B")
        wait_until_sync(lambda: a.cobs(frozen_s).count(logical) >= 15, 10, "A's logical heartbeats")
        thawed_s = time.time()
        os.kill(b.proc.pid, signal.SIGCONT)
        wait_until_sync(lambda: b.said("pair: active -> standby"), 10, "B stands by after the thaw")
        # B finds it did not run and stands by before it acts (docs/redundancy.md): after the
        # thaw it sends its own heartbeat only, no logical heartbeat, SYNC, RPDO, NMT or SDO
        assert set(b.cobs(thawed_s)) <= {COB_HB + B_ID}, sorted(set(b.cobs(thawed_s)))
        assert b.said("did not run") >= 1
        settled_s = time.time()
        wait_until_sync(lambda: a.cobs(settled_s).count(logical) >= 10, 10, "A goes on")
        assert logical not in b.cobs(settled_s)
        assert a.said("active ->") == 0

        # over the run: no NMT, no device left OPERATIONAL or booted, no heartbeat loss reported
        after = seen.since(configured)
        assert not [d for _, c, d in after if c == COB_NMT]
        for node_id in NODES.values():
            states = {d[0] for _, c, d in after if c == COB_HB + node_id}
            assert states == {0x05}, (node_id, states)
        emcys = [(c, d) for _, c, d in seen.since(0) if COB_EMCY < c <= COB_EMCY + 127 and len(d) >= 2]
        assert not [e for e in emcys if int.from_bytes(e[1][:2], "little") == EMCY_HEARTBEAT_LOST], emcys
        stamps = [t for t, c, _ in after if c == logical]
        gap_s = max(y - x for x, y in zip(stamps, stamps[1:], strict=False))
        assert gap_s < CONSUMER_MS / 1000, f"the logical heartbeat paused {gap_s * 1000:.0f} ms"
