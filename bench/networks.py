"""Benchmark 15, several networks: the same frames carried by one CAN network, or split over two
networks of one gateway at half the rate each (``networks:``, two ports of one box).

Two setups, measured interleaved (``ROUNDS`` rounds, each setup once per round, ``PHASE_S``
seconds after a warm-up), each with a gateway *process* (``canopen-gateway run``) fed through
python-can's ``socketcand`` interface by small socketcand servers in this process
(``bench.linerate.SocketcandServer``):

- **one**: one network, one server, ``2 x NODES`` SGH10 nodes (TPDO1 every ``PERIOD_S``,
  heartbeat every 100 ms);
- **two**: two networks, a server each, ``NODES`` nodes on each (node ids 1..NODES on both
  buses; the second network's Modbus units from 101): the same frames per second in all.

Both with the same clients: a Modbus poller reading node 1's position in a tight loop (the
latency from the frame leaving the server to the poller seeing its value, p50 and p99) and a
PLC reading the diagnostics and the position of 8 nodes every 10 ms. Measured: the gateway
process's CPU from /proc/PID/stat, its threads (one ``can-reader`` per bus), frames received
against frames sent. Printed: CPU two / one (target <= 1.1: a second network costs no more
than the frames it carries) and the latencies of both.

Imports: bench.* (linerate's socketcand server, /proc helpers and PLC client, workers, report,
stats, rig), yaml, the standard library; the gateway only as a process.
"""

from __future__ import annotations

import asyncio
import collections
import os
import pathlib
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

import yaml

from bench.linerate import PlcClient, SocketcandServer, http_json, metric, proc_cpu_s, thread_comm
from bench.report import Row, Section
from bench.rig import free_port
from bench.stats import Summary, percentile
from bench.workers import Worker, start_poller

NODES = 20  # per network of the two; twice that on the one
PERIOD_S = 0.010  # TPDO1 of every node: 4,000 frames/s over 40 nodes, plus heartbeats
HEARTBEAT_S = 0.100
SLOTS = 10  # the frames of one period go out in this many writes
PHASE_S = 6.0
WARMUP_S = 2.0
ROUNDS = 2
TARGET_RATIO = 1.1
POSITION = 100  # input registers of the position (int32, high word first)
REPO = pathlib.Path(__file__).resolve().parents[1]


class Feeder:
    """TPDO1 of ``ids`` every ``PERIOD_S`` (position moves every period, node 1's probed) and
    their heartbeats every ``HEARTBEAT_S``, to one socketcand server."""

    def __init__(self, server: SocketcandServer, ids: list[int], probe: bool) -> None:
        self.server, self.ids, self.probe_node = server, ids, probe
        self.stop = threading.Event()
        self.sent = 0
        self.probe: list[tuple[int, float]] = []  # (position of node 1, perf_counter at send)
        self.thread = threading.Thread(target=self._run, name="feeder", daemon=True)

    def start(self) -> Feeder:
        self.thread.start()
        return self

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)

    def _run(self) -> None:
        ids, clock = self.ids, time.perf_counter
        boot = "".join(f"< frame {0x700 + i:03X} {time.time():.6f} 00 >" for i in ids)
        self.server.send(boot.encode())
        slot_s = PERIOD_S / SLOTS
        per_hb = round(HEARTBEAT_S / slot_s)
        groups = [ids[k::SLOTS] for k in range(SLOTS)]
        slot, nxt = 0, clock()
        while not self.stop.is_set():
            cycle, k = divmod(slot, SLOTS)
            ts = f"{time.time():.6f}"
            parts = [f"< frame {0x180 + i:03X} {ts} {(cycle * 8 + i).to_bytes(4, 'little', signed=True).hex()}0700 >"
                     for i in groups[k]]  # fmt: skip
            if slot % per_hb == 0:
                parts += [f"< frame {0x700 + i:03X} {ts} 05 >" for i in ids]
            if self.probe_node and 1 in groups[k]:
                self.probe.append((cycle * 8 + 1, clock()))
            try:
                self.server.send("".join(parts).encode())
            except OSError:
                return
            self.sent += len(parts)
            slot += 1
            nxt += slot_s
            time.sleep(max(0.0, nxt - clock()))


def _config(path: pathlib.Path, ports: list[int]) -> dict[str, Any]:
    """One network on ``ports[0]`` with every node, or a network per port with NODES each."""
    per = NODES * 2 // len(ports)

    def node(i: int, k: int) -> dict[str, Any]:
        return {"name": f"n{k}_{i}", "node_id": i, "profile": "sgh10", "configure": False,
                "supervision": "heartbeat", "heartbeat_ms": 100,
                "modbus": {"unit_id": i + 100 * k}}  # fmt: skip

    nets = [{"name": f"net{k}", "nodes": [node(i, k) for i in range(1, per + 1)],
             "can": {"interface": "socketcand", "host": "127.0.0.1", "port": port, "channel": "can0"},
             "master": {"heartbeat_ms": 1000, "sync_period_ms": 0, "probe_at_start": False}}
            for k, port in enumerate(ports)]  # fmt: skip
    cfg = {
        "gateway": {"name": "networks", "log_level": "warning"},
        "networks": nets,
        "modbus": {"host": "127.0.0.1", "port": free_port()},
        "zenoh": {"mode": "peer", "listen": [f"tcp/127.0.0.1:{free_port()}"]},
        "health": {"host": "127.0.0.1", "port": free_port()},
    }
    path.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return cfg


async def _ready(health: str, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 60
    while True:
        try:
            st = http_json(health + "/healthz")
            if st["ready"] and all(n["operational"] for n in st["nodes"].values()):
                return
        except OSError:
            pass
        if time.monotonic() > deadline or proc.poll() is not None:
            raise RuntimeError("gateway not ready with every node operational within 60 s")
        await asyncio.sleep(0.1)


async def _phase(networks: int) -> dict[str, Any]:
    """One setup's measurement: CPU, frames, node 1's latencies to Modbus, the reader threads."""
    servers = [SocketcandServer() for _ in range(networks)]
    for s in servers:
        s.serve_one()
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-networks-"))
    cfg = _config(tmp / "gateway.yaml", [s.port for s in servers])
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    log = open(tmp / "gateway.log", "w", encoding="utf-8")  # noqa: SIM115 - closed below
    proc = subprocess.Popen([sys.executable, "-m", "canopen_gateway", "run", "-c", str(tmp / "gateway.yaml")],
                            cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    feeders: list[Feeder] = []
    workers: list[Worker] = []
    health = f"http://127.0.0.1:{cfg['health']['port']}"
    try:
        for s in servers:
            await asyncio.to_thread(s.connected.wait, 60)
        per = NODES * 2 // networks
        feeders = [Feeder(s, list(range(1, per + 1)), k == 0).start() for k, s in enumerate(servers)]
        await _ready(health, proc)
        port = cfg["modbus"]["port"]
        poller, plc = start_poller(), Worker(PlcClient, name="plc")
        workers += [poller, plc]
        await asyncio.sleep(WARMUP_S)
        units = [n["modbus"]["unit_id"] for net in cfg["networks"] for n in net["nodes"][:8 // networks]]
        polling = asyncio.ensure_future(poller.acall("poll", "127.0.0.1", port, 1, POSITION, 2, PHASE_S,
                                                     timeout_s=PHASE_S + 60))  # fmt: skip
        plc_run = asyncio.ensure_future(plc.acall("run", port, units, [(0, 16), (POSITION, 3)], 0.01,
                                                  PHASE_S, timeout_s=PHASE_S + 60))  # fmt: skip
        mark = len(feeders[0].probe)
        c0, s0, f0, t0 = proc_cpu_s(proc.pid), sum(f.sent for f in feeders), metric(
            health + "/metrics", "canopen_gateway_frames_in_total"), time.perf_counter()
        polled, plc_result = await polling, await plc_run
        c1, s1, f1, t1 = proc_cpu_s(proc.pid), sum(f.sent for f in feeders), metric(
            health + "/metrics", "canopen_gateway_frames_in_total"), time.perf_counter()
        readers = sorted(n for t in os.listdir(f"/proc/{proc.pid}/task")
                         if (n := thread_comm(proc.pid, int(t))).startswith("can-reader"))  # fmt: skip
    finally:
        for f in feeders:
            f.close()
        for w in workers:
            w.close()
        proc.terminate()
        proc.wait(10)
        log.close()
        for s in servers:
            s.close()
    wall = t1 - t0
    lat = _latencies(polled["changes"], feeders[0].probe[mark:])
    return {"cpu": (c1 - c0) / wall, "fps": (s1 - s0) / wall, "received": (f1 - f0) / wall,
            "p50": percentile(lat, 50), "p99": percentile(lat, 99), "readers": readers,
            "poll_errors": polled["errors"], "plc_errors": plc_result["errors"]}  # fmt: skip


def _latencies(changes: list[tuple[tuple[int, ...], float]], probe: list[tuple[int, float]]) -> list[float]:
    """ms from each probed position's send to the poller's first read of it."""
    seen: dict[int, float] = {}
    for regs, t in changes:
        value = int.from_bytes(bytes([regs[0] >> 8, regs[0] & 0xFF, regs[1] >> 8, regs[1] & 0xFF]), "big", signed=True)
        seen.setdefault(value, t)
    return [(seen[v] - t) * 1000 for v, t in probe if v in seen]


async def run() -> Section:
    results: dict[int, list[dict[str, Any]]] = collections.defaultdict(list)
    for _ in range(ROUNDS):
        for networks in (1, 2):
            results[networks].append(await _phase(networks))
    one, two = results[1], results[2]

    def s(rs: list[dict[str, Any]], key: str) -> Summary:
        return Summary.of([r[key] for r in rs])

    ratio = Summary.of([b["cpu"] / a["cpu"] for a, b in zip(one, two, strict=True)])
    sec = Section(
        key="networks",
        title="15. Several networks: two buses at half rate each against one carrying both",
        method=__doc__.split("\n\n", 1)[1].split("\n\nImports:")[0] if __doc__ else "",
    )
    sec.rows += [
        Row("gateway CPU (share of a core)", s(two, "cpu"), "one network", s(one, "cpu"), ratio,
            f"two / one <= {TARGET_RATIO}", ratio.median <= TARGET_RATIO, digits=3),
        Row("frames/s sent (all buses)", s(two, "fps"), "one network", s(one, "fps")),
        Row("frames/s received (gateway metrics)", s(two, "received"), "one network", s(one, "received")),
        Row("node 1 frame -> Modbus p50 (ms)", s(two, "p50"), "one network", s(one, "p50"), digits=2),
        Row("node 1 frame -> Modbus p99 (ms)", s(two, "p99"), "one network", s(one, "p99"), digits=2),
    ]  # fmt: skip
    sec.notes += [
        f"CPU two / one: {ratio.median:.3f} (target <= {TARGET_RATIO}); reader threads: one "
        f"network {one[0]['readers']}, two networks {two[0]['readers']}",
        f"Modbus errors (poller, PLC): one {[(r['poll_errors'], r['plc_errors']) for r in one]}, "
        f"two {[(r['poll_errors'], r['plc_errors']) for r in two]}",
    ]
    print(f"[bench] networks: CPU two / one = {ratio.median:.3f} (target <= {TARGET_RATIO}); "
          f"p99 one {s(one, 'p99').median:.2f} ms, two {s(two, 'p99').median:.2f} ms")  # fmt: skip
    return sec
