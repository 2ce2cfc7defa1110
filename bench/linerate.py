"""Benchmark 8, line rate: 60 SGH10 nodes on a saturated 1 Mbit/s bus, reaching a gateway
*process* (``canopen-gateway run``) through python-can's ``socketcand`` interface.

The device side is a small socketcand server in this process (its ASCII protocol over TCP on
127.0.0.1: ``< hi >``, ``< open CH >`` / ``< ok >``, ``< rawmode >`` / ``< ok >``, then
``< frame ID SEC.USEC DATA >`` to the client and ``< send ID LEN B0 B1 .. >`` from it). A
generator thread sends what 60 SGH10 would: TPDO1 and TPDO2 (the same position and velocity,
SGH10 manual 4.3.1.1 Table 5) of every node every 13.5 ms, spread over 0.5 ms slots, and every
node's heartbeat every 100 ms: about 9,500 frames/s, a saturated 1 Mbit/s bus. The position of
every node moves every cycle.

Two phases in the same run (three with the pipeline), each ``phase_s`` long, same frames, same
transport:
- **bare**: a python-can socketcand Bus in a process of its own that receives the frames and
  unpacks them with ``struct`` into a dict (what any listener must at least do);
- **gateway**: ``canopen-gateway run`` with a config (default ``publish: change``, every node
  supervised by its 100 ms heartbeat) in a process of its own; a PLC-like Modbus client reads
  20 input registers of 6 nodes every 10 ms, a Modbus poller reads node 1's position in a
  tight loop (latency), and a Zenoh subscriber in another process takes every value; a second
  subscriber takes node 1's position alone (its latency is not queued behind the other keys'
  samples in a Python callback);
- **pipeline** (``scenario(pipeline=...)``, section 9): the bare pipeline (``bench.pipeline``)
  in the gateway's place, under the same clients.

Measured: CPU of each process from /proc/PID/stat, the gateway's CPU per thread
(/proc/PID/task/*/stat, named by a py-spy dump), latency of node 1's positions from the frame
leaving the server to the Modbus poller and to the Zenoh subscriber (p50/p99), frames sent
against ``frames_in`` of the gateway's metrics, nodes not alive (health endpoint, every
second), RSS; then, after the measurement, a py-spy profile of the gateway under the same load
(top functions per thread) when py-spy is installed. Everything listens on 127.0.0.1 and stops
by itself.

Imports: bench.*, tests.pair_bus (the socketcand handshake), python-can, the standard library;
the gateway only as a process.
"""

from __future__ import annotations

import asyncio
import collections
import json
import os
import pathlib
import re
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from typing import Any

import yaml

from bench.machine import rss_kib
from bench.report import Row, Section
from bench.rig import free_port
from bench.stats import Summary, percentile
from bench.workers import Worker, start_poller, start_subscriber
from tests.pair_bus import expect_line

N_NODES = 60
PERIOD_S = 0.0135  # TPDO1 + TPDO2 of every node
SLOT_S = 0.0005
HEARTBEAT_S = 0.100  # SGH10 profile default (boot.heartbeat_ms)
PLC_NODES = 6
#: every input register of an SGH10 node: diagnostics 0-15, position 100-101, velocity 102
PLC_BLOCKS = [(0, 16), (100, 3)]
PLC_REGISTERS = sum(n for _, n in PLC_BLOCKS)
PLC_PERIOD_S = 0.010
CHANNEL = "can0"
POSITION_SCALE = 0.1
SGH10_TPDO = struct.Struct("<ih")  # position int32, velocity int16 (SGH10 manual 4.3.1.1)
REPO = pathlib.Path(__file__).resolve().parents[1]
_CLK_TCK = os.sysconf("SC_CLK_TCK")


# ---------------------------------------------------------------------- device side
class SocketcandServer:
    """One client at a time; frames to it from the generator, frames from it counted."""

    def __init__(self) -> None:
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(1)
        self.port = int(self.listener.getsockname()[1])
        self.conn: socket.socket | None = None
        self.connected = threading.Event()
        self.from_client: collections.Counter[int] = collections.Counter()
        self._threads: list[threading.Thread] = []

    def serve_one(self) -> None:
        """Accept the next client in a thread (handshake, then a reader)."""
        t = threading.Thread(target=self._accept, name="socketcand-accept", daemon=True)
        t.start()
        self._threads.append(t)

    def _accept(self) -> None:
        self.listener.settimeout(60)
        conn, _ = self.listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.sendall(b"< hi >")
        _, buf = expect_line(conn, b"", b"open")
        conn.sendall(b"< ok >")
        expect_line(conn, buf, b"rawmode")
        conn.sendall(b"< ok >")
        # python-can reads the "< ok >" alone (one recv, compared whole): frames sent in the
        # same TCP read would fail its handshake, so the first frames wait a moment
        time.sleep(0.2)
        self.conn = conn
        self.connected.set()
        reader = threading.Thread(target=self._read, args=(conn,), name="socketcand-rx", daemon=True)
        reader.start()

    def _read(self, conn: socket.socket) -> None:
        buf = b""
        while True:
            try:
                chunk = conn.recv(65536)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            *msgs, buf = buf.split(b">")
            for m in msgs:
                parts = m.split()
                if len(parts) >= 3 and parts[1] == b"send":
                    self.from_client[int(parts[2], 16)] += 1

    def send(self, payload: bytes) -> None:
        if self.conn is not None:
            self.conn.sendall(payload)

    def drop_client(self) -> None:
        conn, self.conn = self.conn, None
        self.connected.clear()
        if conn is not None:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            conn.close()

    def close(self) -> None:
        self.drop_client()
        self.listener.close()


class Generator:
    """60 SGH10 on a saturated bus: the frames of each 0.5 ms slot in one TCP write."""

    def __init__(
        self,
        server: SocketcandServer,
        period_s: float = PERIOD_S,
        every_value: bool = False,
        per_frame: bool = False,
    ):
        self.server = server
        #: TPDO1 + TPDO2 of every node every ``period_s``, in 27 slots
        self.period_s = period_s
        self.slot_s = period_s / round(PERIOD_S / SLOT_S)
        #: every frame carries new values (position and velocity), TPDO1 and TPDO2 alike
        self.every_value = every_value
        #: each frame its own TCP write, spread over the slot (one frame per read, as
        #: SocketCAN delivers them); else the frames of a slot in one write
        self.per_frame = per_frame
        self.stop = threading.Event()
        self.sent = {"tpdo": 0, "heartbeat": 0, "bootup": 0}
        self.probe: list[tuple[int, float]] = []  # (position of node 1, perf_counter at send)
        self.max_lag_s = 0.0
        self.cpu_s = 0.0
        self.thread = threading.Thread(target=self._run, name="generator", daemon=True)

    def start(self) -> Generator:
        self.thread.start()
        return self

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)

    def _run(self) -> None:
        c0 = time.thread_time()
        slots_per_period = round(PERIOD_S / SLOT_S)  # 27
        slot_s = self.slot_s
        slots_per_hb = round(HEARTBEAT_S / slot_s)  # 200 at the default rate
        ids = range(1, N_NODES + 1)
        tpdo1 = collections.defaultdict(list)
        tpdo2 = collections.defaultdict(list)
        hb = collections.defaultdict(list)
        for i in ids:
            k = (i - 1) * slots_per_period // N_NODES
            tpdo1[k].append(i)
            tpdo2[(k + slots_per_period // 2) % slots_per_period].append(i)
            hb[(i - 1) * slots_per_hb // N_NODES].append(i)
        clock = time.perf_counter
        pack = SGH10_TPDO.pack
        send = self.server.send
        every_value, per_frame = self.every_value, self.per_frame
        boot = "".join(f"< frame {0x700 + i:03X} {time.time():.6f} 00 >" for i in ids)
        send(boot.encode())
        self.sent["bootup"] += N_NODES
        slot = 0
        nxt = clock()
        while not self.stop.is_set():
            k = slot % slots_per_period
            cycle = slot // slots_per_period
            ts = f"{time.time():.6f}"
            parts = []
            for i in hb[slot % slots_per_hb]:
                parts.append(f"< frame {0x700 + i:03X} {ts} 05 >")
            self.sent["heartbeat"] += len(hb[slot % slots_per_hb])
            probe = None
            for base, nodes in ((0x180, tpdo1[k]), (0x280, tpdo2[k])):
                for i in nodes:
                    if every_value:  # every frame new values: position and velocity
                        value = (cycle * 2 + (base == 0x280)) * 64 + i
                        velocity = value & 0x3FFF
                    else:  # every node's position moves every cycle
                        value, velocity = cycle * 8 + i, 7
                    parts.append(f"< frame {base + i:03X} {ts} {pack(value, velocity).hex()} >")
                    if i == 1 and (not self.probe or self.probe[-1][0] != value):
                        probe = value
                self.sent["tpdo"] += len(nodes)
            if parts and not per_frame:
                if probe is not None:
                    self.probe.append((probe, clock()))
                try:
                    send("".join(parts).encode())
                except OSError:
                    return
            elif parts:
                gap = slot_s / len(parts)
                at = nxt
                for part in parts:
                    delay = at - clock()
                    if delay > 0:
                        time.sleep(delay)
                    if probe is not None and part.startswith(("< frame 181", "< frame 281")):
                        self.probe.append((probe, clock()))
                    try:
                        send(part.encode())
                    except OSError:
                        return
                    at += gap
            slot += 1
            nxt += slot_s
            delay = nxt - clock()
            if delay > 0:
                time.sleep(delay)
            else:
                self.max_lag_s = max(self.max_lag_s, -delay)
            self.cpu_s = time.thread_time() - c0


# ---------------------------------------------------------------------- client processes
class BareListener:
    """python-can socketcand Bus, ``recv`` + ``struct.unpack_from`` into a dict."""

    info = None

    def run(self, port: int, duration_s: float) -> dict[str, Any]:
        import logging

        import can

        # python-can logs a warning whenever a TCP read ends inside a frame; the gateway logs
        # them as `canopen-gateway run` does (warnings, to its log file)
        logging.getLogger("can").setLevel(logging.ERROR)
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel=CHANNEL)
        values: dict[int, tuple[int, int]] = {}
        unpack = SGH10_TPDO.unpack_from
        n = 0
        end = time.perf_counter() + duration_s
        try:
            while time.perf_counter() < end:
                msg = bus.recv(0.1)
                if msg is None:
                    continue
                n += 1
                if len(msg.data) == 6:
                    values[msg.arbitration_id] = unpack(msg.data)
        finally:
            bus.shutdown()
        return {"frames": n, "ids": len(values)}


class PlcClient:
    """A PLC: every ``period_s`` reads each of ``blocks`` (address, count) of input registers
    of each of ``units``."""

    info = None

    def run(
        self,
        port: int,
        units: list[int],
        blocks: list[tuple[int, int]],
        period_s: float,
        duration_s: float,
    ) -> dict[str, Any]:
        from pymodbus.client import ModbusTcpClient

        c = ModbusTcpClient("127.0.0.1", port=port, timeout=2)
        if not c.connect():
            raise ConnectionError(f"cannot connect to 127.0.0.1:{port}")
        n = errors = 0
        clock = time.perf_counter
        nxt = clock()
        end = nxt + duration_s
        try:
            while clock() < end:
                for u in units:
                    for address, count in blocks:
                        if c.read_input_registers(address, count=count, device_id=u).isError():
                            errors += 1
                        n += 1
                nxt += period_s
                time.sleep(max(0.0, nxt - clock()))
        finally:
            c.close()
        return {"requests": n, "errors": errors}


# ---------------------------------------------------------------------- /proc helpers
def proc_cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
        stat = f.read()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK


def thread_cpu_s(pid: int) -> dict[int, float]:
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            out[int(tid)] = _task_cpu(pid, tid)
        except OSError:
            continue  # the thread ended meanwhile
    return out


def thread_detail(pid: int) -> dict[int, tuple[float, int, int, float]]:
    """Per thread: system CPU seconds, voluntary and involuntary context switches so far, CPU
    seconds (user + system)."""
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/stat", encoding="ascii", errors="replace") as f:
                stat = f.read()
            with open(f"/proc/{pid}/task/{tid}/status", encoding="ascii", errors="replace") as f:
                status = dict(line.split(":", 1) for line in f.read().splitlines() if ":" in line)
        except OSError:
            continue  # the thread ended meanwhile
        fields = stat[stat.rindex(")") + 2 :].split()
        out[int(tid)] = (
            int(fields[12]) / _CLK_TCK,
            int(status["voluntary_ctxt_switches"]),
            int(status["nonvoluntary_ctxt_switches"]),
            (int(fields[11]) + int(fields[12])) / _CLK_TCK,
        )
    return out


def _task_cpu(pid: int, tid: str) -> float:
    with open(f"/proc/{pid}/task/{tid}/stat", encoding="ascii", errors="replace") as f:
        stat = f.read()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK


def thread_comm(pid: int, tid: int) -> str:
    try:
        with open(f"/proc/{pid}/task/{tid}/comm", encoding="ascii", errors="replace") as f:
            return f.read().strip()
    except OSError:
        return "?"


def pyspy() -> str | None:
    found = shutil.which("py-spy")
    if found:
        return found
    beside = pathlib.Path(sys.executable).with_name("py-spy")
    return str(beside) if beside.exists() else None


#: leaf frames where a thread waits (left out of the busy samples)
_WAITING = re.compile(r"^(select|.*\.select|.*\.wait|wait|_wait_for_tstate_lock|sleep|.*\.poll) ")


def profile_threads(pid: int, duration_s: float, top: int = 8) -> dict[str, Any]:
    """``py-spy record --threads --format raw``: per Python thread (native id, name), the leaf
    functions of its busy samples (waits left out), as shares of those samples."""
    exe = pyspy()
    if exe is None:
        return {}
    with tempfile.NamedTemporaryFile(suffix=".txt", delete=False) as f:
        out = f.name
    try:
        subprocess.run(
            [exe, "record", "--pid", str(pid), "--duration", str(int(duration_s)), "--rate", "250",
             "--threads", "--format", "raw", "--output", out],
            capture_output=True, text=True, timeout=duration_s + 60,
        )  # fmt: skip
        text = pathlib.Path(out).read_text(encoding="utf-8", errors="replace")
    finally:
        os.unlink(out)
    per_thread: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    names: dict[int, str] = {}
    for line in text.splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        frames = stack.split(";")
        m = re.match(r"thread \((\d+)\)(?:: (.*))?", frames[0])
        if m is None:
            continue
        names[int(m.group(1))] = m.group(2) or m.group(1)
        leaf = frames[-1]
        if len(frames) < 2 or _WAITING.match(leaf):
            continue
        per_thread[m.group(2) or m.group(1)][leaf] += int(count)
    top_by_thread = {}
    rate = 250
    for thread, counter in sorted(per_thread.items(), key=lambda kv: -sum(kv[1].values())):
        total = sum(counter.values())
        top_by_thread[f"{thread} ({total} busy samples, {total / rate / duration_s:.0%} busy)"] = [
            (fn, c / total) for fn, c in counter.most_common(top)
        ]
    return {"names": names, "top": top_by_thread}


def http_json(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=2) as r:
        return json.loads(r.read())


def metric(url: str, name: str) -> float:
    with urllib.request.urlopen(url, timeout=2) as r:
        for line in r.read().decode().splitlines():
            if line.startswith(name + " ") or line.startswith(name + "{"):
                return float(line.rsplit(" ", 1)[1])
    return math_nan()


def metrics(url: str) -> dict[str, float]:
    """The unlabelled samples of a Prometheus text page."""
    out = {}
    with urllib.request.urlopen(url, timeout=2) as r:
        for line in r.read().decode().splitlines():
            name, _, value = line.partition(" ")
            if line and not line.startswith("#") and "{" not in name:
                out[name] = float(value)
    return out


def math_nan() -> float:
    return float("nan")



def reader_figures(
    per_thread: list[tuple[str, int, float]],
    d0: dict[int, tuple[float, int, int, float]],
    d1: dict[int, tuple[float, int, int, float]],
    c0: dict[str, float],
    c1: dict[str, float],
    wall: float,
) -> dict[str, float]:
    """The reader's cost per burst (one wake-up each) and per frame, the ``zenoh-publish``
    thread's per frame (the values the reader marked), and the context switches per burst: of
    the reader, and of every thread of the process."""
    ns = "canopen_gateway_"
    frames = c1.get(ns + "frames_in_total", 0) - c0.get(ns + "frames_in_total", 0)
    bursts = c1.get(ns + "can_bursts_total", 0) - c0.get(ns + "can_bursts_total", 0)
    reader = next((tid for name, tid, _ in per_thread if name == "can-reader"), None)
    if reader is None:  # not named without a profile: the busiest thread but the main one
        main = min(tid for _, tid, _ in per_thread)
        reader = next((tid for _, tid, _ in per_thread if tid != main), None)
    out = {"frames_in_window": frames, "bursts": bursts,
           "frames_per_burst": frames / bursts if bursts else math_nan()}  # fmt: skip
    if reader is None or reader not in d0 or reader not in d1 or not bursts:
        return out
    r_cpu = d1[reader][3] - d0[reader][3]
    pub = next((tid for name, tid, _ in per_thread if name == "zenoh-publish"), None)
    if pub is not None and pub in d0 and pub in d1:
        p_cpu = d1[pub][3] - d0[pub][3]
        out.update(publish_cpu=p_cpu / wall, publish_us_per_frame=p_cpu / max(1, frames) * 1e6)
    r_sw = (d1[reader][1] - d0[reader][1]) + (d1[reader][2] - d0[reader][2])
    all_sw = sum((d1[t][1] - d0[t][1]) + (d1[t][2] - d0[t][2]) for t in d1 if t in d0)
    out.update(
        reader_cpu=r_cpu / wall,
        reader_us_per_burst=r_cpu / bursts * 1e6,
        reader_us_per_frame=r_cpu / max(1, frames) * 1e6,
        reader_switches_per_burst=r_sw / bursts,
        switches_per_burst=all_sw / bursts,
    )
    return out


def _latencies(records: list[tuple[int, Any, float]], probe: list[tuple[int, float]]) -> list[float]:
    """ms from each probed position's send to its first sample at a subscriber."""
    seen: dict[int, float] = {}
    for _, v, t in records:
        if isinstance(v, dict):  # publish: pdo
            v = v["signals"]["position"]["value"]
        seen.setdefault(round(v / POSITION_SCALE), t)
    return [(seen[v] - t) * 1000 for v, t in probe if v in seen]


# ---------------------------------------------------------------------- phases
async def _bare_phase(phase_s: float, gen_kw: dict[str, Any] | None = None) -> dict[str, Any]:
    server = SocketcandServer()
    server.serve_one()
    bare = Worker(BareListener, name="bare-listener")
    gen: Generator | None = None
    try:
        call = asyncio.ensure_future(bare.acall("run", server.port, phase_s + 2.0,
                                                timeout_s=phase_s + 60))  # fmt: skip
        await asyncio.to_thread(server.connected.wait, 30)
        gen = Generator(server, **(gen_kw or {})).start()
        await asyncio.sleep(1.0)
        pid = bare.proc.pid
        assert pid is not None
        c0, s0, t0 = proc_cpu_s(pid), dict(gen.sent), time.perf_counter()
        d0 = thread_detail(pid)
        await asyncio.sleep(phase_s)
        d1 = thread_detail(pid)
        c1, s1, t1 = proc_cpu_s(pid), dict(gen.sent), time.perf_counter()
        result = await call
    finally:
        if gen is not None:
            gen.close()
        server.close()
        bare.close()
    wall = t1 - t0
    frames = (s1["tpdo"] + s1["heartbeat"]) - (s0["tpdo"] + s0["heartbeat"])
    d = [sum(d1[t][i] - d0[t][i] for t in d1 if t in d0) for i in range(3)]
    # its receive loop is the process's busiest thread: its CPU per frame
    busy = max((t for t in d1 if t in d0), key=lambda t: d1[t][3] - d0[t][3])
    return {"cpu": (c1 - c0) / wall, "fps": frames / wall, "received": result["frames"],
            "lag_ms": gen.max_lag_s * 1000 if gen else math_nan(),
            "sys": d[0] / wall, "switches_per_frame": (d[1] + d[2]) / frames,
            "us_per_frame": (d1[busy][3] - d0[busy][3]) / max(1, frames) * 1e6}  # fmt: skip


def _gateway_config(
    path: pathlib.Path,
    can_port: int,
    publish: str = "change",
    zenoh: bool = True,
    batch_ms: float | None = None,
    journal: dict[str, Any] | None = None,
) -> dict[str, Any]:
    cfg = {
        "gateway": {"name": "linerate", "log_level": "warning"},
        "can": {"interface": "socketcand", "host": "127.0.0.1", "port": can_port,
                "channel": CHANNEL, "tcp_tune": True},
        "master": {"heartbeat_ms": 1000, "sync_period_ms": 0, "probe_at_start": False},
        "nodes": [
            {"name": f"n{i}", "node_id": i, "profile": "sgh10", "configure": False,
             "supervision": "heartbeat", "heartbeat_ms": 100}
            for i in range(1, N_NODES + 1)
        ],
        "modbus": {"host": "127.0.0.1", "port": free_port()},
        "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{free_port()}"], "publish": publish,
                  "enabled": zenoh},
        "health": {"host": "127.0.0.1", "port": free_port()},
    }  # fmt: skip
    if batch_ms is not None:  # else the gateway's default
        cfg["zenoh"]["batch_ms"] = batch_ms
    if journal is not None:  # the store and forward journal (bench/journal.py)
        cfg["journal"] = journal
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return cfg


async def _gateway_phase(
    phase_s: float,
    profile_s: float,
    gen_kw: dict[str, Any] | None = None,
    publish: str = "change",
    zenoh: bool = True,
    batch_ms: float | None = None,
    pipeline: str = "",
    journal: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The gateway's phase of a scenario, or (``pipeline``: "bare", or "split" with its Modbus
    server in a second process) the bare pipeline's in its place."""
    server = SocketcandServer()
    server.serve_one()
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-linerate-"))
    if journal is not None and "path" not in journal:
        journal = {**journal, "path": str(tmp / "journal")}
    cfg = _gateway_config(tmp / "gateway.yaml", server.port, publish, zenoh, batch_ms, journal)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    log = open(tmp / "gateway.log", "w", encoding="utf-8")  # noqa: SIM115 - closed below
    argv = [sys.executable, "-m", "canopen_gateway", "run", "-c", str(tmp / "gateway.yaml")]
    if pipeline:  # the bare pipeline (bench/pipeline.py) on the same ports, in its place
        argv = [sys.executable, "-m", "bench.pipeline", "--can-port", str(server.port),
                "--channel", CHANNEL, "--modbus-port", str(cfg["modbus"]["port"]),
                "--listen", cfg["zenoh"]["listen"][0], "--nodes", str(N_NODES)]  # fmt: skip
        if pipeline == "split":
            argv.append("--split")
    proc = subprocess.Popen(argv, cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    gen: Generator | None = None
    workers: list[Worker] = []
    health = f"http://127.0.0.1:{cfg['health']['port']}"
    try:
        await asyncio.to_thread(server.connected.wait, 60)
        if not server.connected.is_set():
            raise RuntimeError("the gateway did not connect to the socketcand server")
        gen = Generator(server, **(gen_kw or {})).start()
        deadline = time.monotonic() + 60
        while not pipeline:  # the pipeline has no health: the subscribers' wait below
            try:
                st = http_json(health + "/healthz")
                if all(n["operational"] for n in st["nodes"].values()) and st["ready"]:
                    break
            except OSError:
                pass
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError("gateway not ready with every node operational within 60 s")
            await asyncio.sleep(0.1)
        endpoint = cfg["zenoh"]["listen"][0]
        prefix = "canopen/linerate"
        # publish: pdo puts node 1's TPDO1 and TPDO2 (one record) on tpdo/1
        pdo = publish == "pdo"
        probe_key = f"{prefix}/n1/tpdo/1" if pdo else f"{prefix}/n1/value/position"
        parse = ["json_all" if pdo else "json"]
        sub = start_subscriber([endpoint], [(f"{prefix}/**", "count")], probe_key)
        workers.append(sub)
        for _ in range(200 if zenoh else 0):  # the subscriber is matched once it sees node 1 move
            if await sub.acall("wait", 1, 0.05, 0.05):
                break
        sub0 = await sub.acall("take", parse)
        # a second subscriber on node 1's position alone: its latency is not queued behind
        # the other 119 keys' samples in a Python callback
        psub = start_subscriber([endpoint], [(probe_key, "record")])
        workers.append(psub)
        for _ in range(200 if zenoh else 0):
            if await psub.acall("wait", 1, 0.05, 0.05):
                break
        await psub.acall("take", parse)
        poller = start_poller()
        workers.append(poller)
        plc = Worker(PlcClient, name="plc")
        workers.append(plc)
        mb_port = cfg["modbus"]["port"]
        latency_s = phase_s / 2
        plc_s = phase_s + latency_s + 1.5
        plc_call = asyncio.ensure_future(plc.acall(
            "run", mb_port, list(range(1, PLC_NODES + 1)), PLC_BLOCKS, PLC_PERIOD_S, plc_s,
            timeout_s=plc_s + 60))  # fmt: skip
        await asyncio.sleep(0.5)
        not_alive = 0

        async def window(duration_s: float) -> tuple[float, dict[int, float], float]:
            nonlocal not_alive
            c0, th0, t0 = proc_cpu_s(proc.pid), thread_cpu_s(proc.pid), time.perf_counter()
            end = t0 + duration_s
            while time.perf_counter() < end:
                await asyncio.sleep(min(1.0, max(0.0, end - time.perf_counter())))
                if pipeline:
                    continue
                st = http_json(health + "/healthz")
                not_alive = max(not_alive, sum(1 for n in st["nodes"].values() if not n["alive"]))
            c1, th1, t1 = proc_cpu_s(proc.pid), thread_cpu_s(proc.pid), time.perf_counter()
            wall = t1 - t0
            return (c1 - c0) / wall, {t: (c - th0.get(t, 0.0)) / wall for t, c in th1.items()}, t0

        # the gateway's counters are copied in at every scrape (the bare pipeline has none)
        counts0 = {} if pipeline else metrics(health + "/metrics")
        sent0, tw0 = dict(gen.sent), time.perf_counter()
        detail0 = thread_detail(proc.pid)
        cpu, threads_cpu, tq0 = await window(phase_s)  # PLC + Zenoh: the load of the issue
        tq1 = time.perf_counter()  # [tq0, tq1): the PLC alone, no poller
        detail1 = thread_detail(proc.pid)
        sent1, tw1 = dict(gen.sent), time.perf_counter()
        counts1 = {} if pipeline else metrics(health + "/metrics")
        comms = {tid: thread_comm(proc.pid, tid) for tid in threads_cpu}
        rss = rss_kib(proc.pid)
        # latency: a Modbus poller in a tight loop on node 1's position meanwhile
        poll_call = asyncio.ensure_future(poller.acall(
            "poll", "127.0.0.1", mb_port, 1, 100, 2, latency_s, timeout_s=latency_s + 60))  # fmt: skip
        cpu_polled, _, t0 = await window(latency_s - 0.2)
        t1 = time.perf_counter()
        polled = await poll_call
        profile = await asyncio.to_thread(profile_threads, proc.pid, profile_s) if profile_s else {}
        plc_result = await plc_call
        gen.close()
        await asyncio.sleep(1.5)  # the gateway copies its counters into the metrics every second
        frames_in = (
            math_nan() if pipeline else metric(health + "/metrics", "canopen_gateway_frames_in_total")
        )
        z = await sub.acall("take", parse)
        pz = await psub.acall("take", parse) if zenoh else {"records": []}
    finally:
        if gen is not None:
            gen.close()
        for w in workers:
            w.close()
        proc.terminate()
        try:
            await asyncio.to_thread(proc.wait, 10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()
        server.close()
    frames_sent_total = sum(gen.sent.values())
    names = profile.get("names", {}) if profile else {}
    per_thread = [
        (names.get(tid) or comms.get(tid) or str(tid), tid, c) for tid, c in threads_cpu.items()
    ]
    per_thread.sort(key=lambda x: -x[2])
    probe = [(v, t) for v, t in gen.probe if t0 <= t < t1]
    mb_seen: dict[int, float] = {}
    for regs, t in polled["changes"]:
        v = (regs[0] << 16) | regs[1]
        mb_seen.setdefault(v - (1 << 32) if v >= 1 << 31 else v, t)
    mb_lat = [(mb_seen[v] - t) * 1000 for v, t in probe if v in mb_seen]
    z_lat = _latencies(z["records"], probe)
    # frame -> Zenoh with the PLC alone (no poller), at a subscriber on node 1's position only
    quiet = [(v, t) for v, t in gen.probe if tq0 <= t < tq1]
    zq_lat = _latencies(pz["records"], quiet)
    value_samples = sum(c for k, c in z["counts"].items() if "/value/" in k or "/tpdo/" in k)
    return {
        "cpu": cpu,
        "cpu_polled": cpu_polled,
        "fps": ((sent1["tpdo"] + sent1["heartbeat"]) - (sent0["tpdo"] + sent0["heartbeat"]))
        / (tw1 - tw0),
        "frames_sent": frames_sent_total,
        "frames_in": frames_in,
        "not_alive": not_alive,
        "rss_mib": rss.get("VmRSS", 0) / 1024,
        "hwm_mib": rss.get("VmHWM", 0) / 1024,
        "threads": per_thread,
        "switches": {
            name: (
                (detail1[tid][0] - detail0[tid][0]) / (tw1 - tw0),
                (detail1[tid][1] - detail0[tid][1]) / (tw1 - tw0),
                (detail1[tid][2] - detail0[tid][2]) / (tw1 - tw0),
            )
            for name, tid, _c in per_thread
            if tid in detail0 and tid in detail1
        },
        **reader_figures(per_thread, detail0, detail1, counts0, counts1, tw1 - tw0),
        "mb_p50": percentile(mb_lat, 50), "mb_p99": percentile(mb_lat, 99),
        "z_p50": percentile(z_lat, 50), "z_p99": percentile(z_lat, 99),
        "zq_p50": percentile(zq_lat, 50), "zq_p99": percentile(zq_lat, 99),
        "probes": len(probe), "mb_seen": len(mb_lat), "z_seen": len(z_lat),
        "plc_rps": plc_result["requests"] / plc_s,
        "poller_rps": polled["polls"] / latency_s,
        "plc_requests": plc_result["requests"], "plc_errors": plc_result["errors"],
        "poller_polls": polled["polls"],
        "value_samples_per_s": value_samples / max(1e-9, z["at"] - sub0["at"]),
        "sub_cpu": (z["cpu_s"] - sub0["cpu_s"]) / max(1e-9, z["at"] - sub0["at"]),
        "lag_ms": gen.max_lag_s * 1000 if gen else math_nan(),
        "gen_cpu": gen.cpu_s,
        "profile": profile,
        "from_gateway": dict(server.from_client),
    }  # fmt: skip


async def run(phase_s: float = 20.0, profile_s: float = 8.0) -> Section:
    sec = Section(
        key="linerate",
        title=f"8. Line rate: {N_NODES} SGH10 on a saturated 1 Mbit/s bus through socketcand",
        method=(
            f"{N_NODES} SGH10 nodes played by a socketcand server in the bench process (ASCII "
            "protocol over TCP, 127.0.0.1): TPDO1 + TPDO2 of every node every "
            f"{PERIOD_S * 1000:g} ms in {SLOT_S * 1000:g} ms slots, heartbeats every "
            f"{HEARTBEAT_S * 1000:g} ms, every position moving each cycle (about 9,500 frames/s). "
            f"Phase **bare** ({phase_s:g} s): a python-can `socketcand` Bus in its own process "
            "receives the frames and unpacks them with `struct`. Phase **gateway** "
            f"({phase_s:g} s): `canopen-gateway run` (default `publish: change`, heartbeat "
            f"supervision) in its own process, a PLC-like client reading {PLC_REGISTERS} input "
            f"registers of {PLC_NODES} nodes (0-15, 100-102: two requests per node) every "
            f"{PLC_PERIOD_S * 1000:g} ms (CPU measured with this load), then for half as long "
            "also a Modbus poller "
            "reading node 1's position in a tight loop, a Zenoh subscriber on every value, each "
            "a process of its own. CPU from /proc/PID/stat (and per thread from "
            "/proc/PID/task); latency of node 1's positions from the frame leaving the server "
            f"to the poller and to the subscriber; then a {profile_s:g} s py-spy profile "
            "(`record --threads --format raw`, 250 Hz) of the gateway under the "
            "same load."
        ),
    )
    bare = await _bare_phase(phase_s)
    gw = await _gateway_phase(phase_s, profile_s)
    s = Summary.of
    ratio = gw["cpu"] / bare["cpu"] if bare["cpu"] else math_nan()
    lost = gw["frames_sent"] - gw["frames_in"]
    sec.rows += [
        Row("frames/s sent by the device side (bare phase / gateway phase)", s([gw["fps"]]),
            "bare phase", s([bare["fps"]])),
        Row("CPU, PLC + Zenoh load, % of one core", s([gw["cpu"] * 100]), "bare listener", s([bare["cpu"] * 100]),
            s([ratio]), "<= 2.5x bare", ratio <= 2.5, digits=1),
        Row("gateway CPU, % of one core", s([gw["cpu"] * 100]), target="<= 30%",
            met=gw["cpu"] <= 0.30, digits=1),
        Row("gateway CPU with the latency poller added (tight loop), %", s([gw["cpu_polled"] * 100]),
            digits=1),
        Row("latency frame -> Modbus poller p50 (ms)", s([gw["mb_p50"]]), digits=3),
        Row("latency frame -> Modbus poller p99 (ms)", s([gw["mb_p99"]]), target="<= 1 ms",
            met=gw["mb_p99"] <= 1.0, digits=3),
        Row("latency frame -> Zenoh subscriber p50 (ms)", s([gw["z_p50"]]), digits=3),
        Row("latency frame -> Zenoh subscriber p99 (ms)", s([gw["z_p99"]]), target="<= 1 ms",
            met=gw["z_p99"] <= 1.0, digits=3),
        Row("frames sent but not received by the gateway (frames_in)", s([lost]), target="0",
            met=lost == 0),
        Row("nodes not alive (worst 1 s sample)", s([gw["not_alive"]]), target="0",
            met=gw["not_alive"] == 0),
        Row("gateway RSS (MiB)", s([gw["rss_mib"]]), target="<= 100 MiB",
            met=gw["rss_mib"] <= 100, digits=1),
    ]  # fmt: skip
    threads = ", ".join(
        f"{name} {cpu * 100:.1f}%" for name, _tid, cpu in gw["threads"] if cpu >= 0.005
    )
    fps_gw = gw["fps"]
    switches = "; ".join(
        f"{name} {sys_s * 100:.1f}% system, {vol:,.0f} voluntary + {invol:,.0f} involuntary/s "
        f"({(vol + invol) / fps_gw:.2f} per frame)"
        for name, (sys_s, vol, invol) in gw["switches"].items()
        if vol + invol >= 100
    )
    sec.notes.append(
        "System time and context switches by thread (/proc/PID/task/*/stat and status, same "
        f"window): {switches}. The bare listener: {bare['sys'] * 100:.1f}% system, "
        f"{bare['switches_per_frame']:.2f} context switches per frame in all."
    )
    sec.notes.append(
        f"Gateway CPU by thread (% of one core, PLC + Zenoh load): {threads}. Modbus: the PLC "
        f"{gw['plc_rps']:,.0f} requests/s ({gw['plc_requests']:,} reads, {gw['plc_errors']} "
        f"errors), the latency poller {gw['poller_rps']:,.0f} requests/s while it ran; Zenoh: {gw['value_samples_per_s']:,.0f} value "
        f"samples/s at the subscriber (its CPU {gw['sub_cpu'] * 100:.0f}%); node 1 positions "
        f"sent {gw['probes']:,}, seen by the poller {gw['mb_seen']:,}, by the subscriber "
        f"{gw['z_seen']:,}. Generator: worst lag behind its slots {gw['lag_ms']:.1f} ms "
        f"(bare phase {bare['lag_ms']:.1f} ms). Frames the gateway sent to the bus: "
        + ", ".join(f"0x{k:03X} x{v}" for k, v in sorted(gw["from_gateway"].items())[:6])
        + (" ..." if len(gw["from_gateway"]) > 6 else "")
        + f". Peak RSS (VmHWM) {gw['hwm_mib']:.1f} MiB."
    )
    for thread, top in (gw["profile"] or {}).get("top", {}).items():
        sec.notes.append(
            f"py-spy, {thread}: "
            + "; ".join(f"{fn} {share * 100:.0f}%" for fn, share in top)
        )
    return sec


async def scenario(
    fps: float | None = None,
    every_value: bool = False,
    per_frame: bool = False,
    publish: str = "change",
    phase_s: float = 10.0,
    profile_s: float = 0.0,
    zenoh: bool = True,
    batch_ms: float | None = None,
    pipeline: str = "",
) -> dict[str, Any]:
    """One paired run, bare listener then gateway, of a line-rate scenario: ``fps`` frames/s
    (TPDOs + heartbeats of the 60 nodes; default the bench's 9,489), every frame with new values
    or not, each frame its own TCP write or a slot's frames in one; ``publish`` the config's
    ``zenoh.publish``. With ``pipeline`` ("bare" or "split"), then the bare pipeline
    (``bench.pipeline``) under the same load: its figures as ``pipe_*`` (with "split" the CPU
    is the reading process's alone, not its Modbus process's)."""
    gen_kw: dict[str, Any] = {"every_value": every_value, "per_frame": per_frame}
    if fps is not None:
        if fps <= N_NODES / HEARTBEAT_S:
            raise ValueError(f"{fps} frames/s: the heartbeats alone are {N_NODES / HEARTBEAT_S:g}")
        gen_kw["period_s"] = 2 * N_NODES / (fps - N_NODES / HEARTBEAT_S)
    bare = await _bare_phase(phase_s, gen_kw)
    gw = await _gateway_phase(phase_s, profile_s, gen_kw, publish, zenoh, batch_ms)
    keys = ("fps", "cpu", "mb_p50", "mb_p99", "z_p50", "z_p99", "zq_p50", "zq_p99",
            "frames_per_burst",
            "reader_cpu", "reader_us_per_burst", "reader_us_per_frame", "publish_cpu",
            "publish_us_per_frame",
            "reader_switches_per_burst", "switches_per_burst", "value_samples_per_s", "not_alive")  # fmt: skip
    out = {k: gw.get(k, math_nan()) for k in keys}
    out.update(
        bare_cpu=bare["cpu"],
        ratio=gw["cpu"] / bare["cpu"] if bare["cpu"] else math_nan(),
        bare_us_per_frame=bare["us_per_frame"],
        lost=gw["frames_sent"] - gw["frames_in"],
        threads={
            f"{name} {tid}": round(c * 100, 1) for name, tid, c in gw["threads"] if c >= 0.005
        },
        profile=gw["profile"].get("top", {}) if gw["profile"] else {},
    )
    if pipeline:
        pipe = await _gateway_phase(phase_s, 0.0, gen_kw, pipeline=pipeline)
        out.update({f"pipe_{k}": pipe.get(k, math_nan()) for k in keys})
        out.update(
            pipe_ratio=pipe["cpu"] / bare["cpu"] if bare["cpu"] else math_nan(),
            gw_to_pipe=gw["cpu"] / pipe["cpu"] if pipe["cpu"] else math_nan(),
        )
    return out


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m bench.linerate", description=scenario.__doc__)
    ap.add_argument("--fps", type=float, default=None)
    ap.add_argument("--every-value", action="store_true")
    ap.add_argument("--per-frame", action="store_true")
    ap.add_argument("--publish", default="change")
    ap.add_argument("--phase", type=float, default=10.0)
    ap.add_argument("--profile", type=float, default=0.0)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--no-zenoh", action="store_true", help="the gateway without Zenoh")
    ap.add_argument("--batch-ms", type=float, default=None, help="zenoh.batch_ms (default: the gateway's)")
    ap.add_argument("--pipeline", choices=["bare", "split"], default="",
                    help="then the bare pipeline under the same load (split: Modbus in a second process)")  # fmt: skip
    args = ap.parse_args()
    for _ in range(args.repeat):
        r = asyncio.run(scenario(args.fps, args.every_value, args.per_frame, args.publish,
                                 args.phase, args.profile, not args.no_zenoh,
                                 args.batch_ms, args.pipeline))  # fmt: skip
        print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main()
