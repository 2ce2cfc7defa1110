"""Benchmark 2, latency: CAN frame -> value seen by a polling Modbus client, and by a Zenoh
subscriber, against a bare pipeline doing the same jobs with the least code.

An injector thread sends one TPDO (a new position each time) every 1-3 ms (random) and notes
the send time. A Modbus client in another process (pymodbus ``AsyncModbusTcpClient``) polls the
position registers in a tight loop and notes when each new value is first seen; a Zenoh
subscriber in a third process notes when each sample arrives. Latency = seen - sent (one clock:
CLOCK_MONOTONIC). The polling client adds up to one request round trip to every figure, on both
sides alike.

Bare pipeline: a python-can listener thread unpacks the frame and (a) hands the registers to a
pymodbus server with ``await server.async_setValues`` on its event loop, (b) puts the raw bytes
on a Zenoh publisher. The gateway does decode -> process image (read by Modbus on request) ->
JSON publication. Windows of the two alternate, repetition by repetition.

Imports: bench.*, gateway (through bench.rig), python-can, pymodbus, zenoh.
"""

from __future__ import annotations

import asyncio
import json
import random
import threading
import time
from typing import Any

import can
import zenoh
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from bench.report import Row, Section
from bench.rig import (
    SGH10_TPDO,
    TPDO1_BASE,
    Injector,
    bench_config,
    bench_node,
    free_port,
    start_gateway,
    unique_channel,
    zenoh_endpoint,
)
from bench.stats import Summary, paired_ratios, percentile
from bench.workers import start_poller, start_subscriber

POSITION_REGISTER = 100  # gateway register map: first signal register of a node's unit
POSITION_SCALE = 0.1
BARE_KEY = "bare/n1/value/position"
FC_WRITE_REGISTERS = 16


def registers_of(value: int) -> list[int]:
    """int32 as two registers, high word first (the gateway's default word order)."""
    u = value & 0xFFFFFFFF
    return [u >> 16, u & 0xFFFF]


def value_of(regs: tuple[int, ...]) -> int:
    v = (regs[0] << 16) | regs[1]
    return v - (1 << 32) if v >= 1 << 31 else v


class BarePipeline:
    """python-can listener -> pymodbus server registers (SimDevice) and a Zenoh put."""

    def __init__(self, channel: str):
        self.channel = channel
        self.modbus_port = free_port()
        self.zenoh_endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.server: ModbusTcpServer | None = None
        self.session: Any = None
        self._running = False

    async def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        dev = SimDevice(id=1, simdata=[SimData(0, count=103, datatype=DataType.REGISTERS)])
        self.server = ModbusTcpServer(dev, address=("127.0.0.1", self.modbus_port))
        await self.server.serve_forever(background=True)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", json.dumps([self.zenoh_endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = await asyncio.to_thread(zenoh.open, conf)
        self.pub = self.session.declare_publisher(BARE_KEY)
        self.bus = can.Bus(interface="virtual", channel=self.channel)
        self._running = True
        self.thread = threading.Thread(target=self._run, name="bare-pipeline", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        unpack = SGH10_TPDO.unpack_from
        server, loop, put = self.server, self.loop, self.pub.put
        assert server is not None

        def set_registers(regs: list[int]) -> None:
            loop.create_task(server.async_setValues(1, FC_WRITE_REGISTERS, POSITION_REGISTER, regs))

        while self._running:
            msg = self.bus.recv(0.05)
            if msg is None:
                continue
            position, _velocity = unpack(msg.data)
            loop.call_soon_threadsafe(set_registers, registers_of(position))
            put(bytes(msg.data))

    async def stop(self) -> None:
        self._running = False
        await asyncio.to_thread(self.thread.join, 2.0)
        self.bus.shutdown()
        self.pub.undeclare()
        await asyncio.to_thread(self.session.close)
        if self.server is not None:
            await self.server.shutdown()


def _paced_send(
    inj: Injector, node_id: int, first: int, duration_s: float
) -> list[tuple[int, float]]:
    """One TPDO every 1-3 ms (random) for ``duration_s``; returns (position, send time)."""
    rnd = random.Random(first)
    sent = []
    clock = time.perf_counter
    end = clock() + duration_s
    value = first
    pack = SGH10_TPDO.pack
    cob = TPDO1_BASE + node_id
    while clock() < end:
        msg = can.Message(arbitration_id=cob, data=pack(value, 7), is_extended_id=False,
                          timestamp=time.time())  # fmt: skip
        t = clock()
        inj.send_direct(msg)
        sent.append((value, t))
        value += 1
        time.sleep(rnd.uniform(0.001, 0.003))
    return sent


def latencies_ms(sent: list[tuple[int, float]], seen: dict[int, float]) -> list[float]:
    return [(seen[v] - t) * 1000.0 for v, t in sent if v in seen]


async def run(reps: int = 5, window_s: float = 2.0) -> Section:
    sec = Section(
        key="latency",
        title="2. Latency: CAN frame -> Modbus client / Zenoh subscriber",
        method=(
            f"{reps} repetitions of a {window_s:g} s window per pipeline, gateway and bare "
            "alternating; one TPDO every 1-3 ms (random), about "
            f"{int(window_s / 0.002):,} samples per window. Modbus: pymodbus "
            "AsyncModbusTcpClient in its own process polling the 2 position registers in a "
            "tight loop; Zenoh: subscriber in its own process over TCP loopback. Bare: "
            "python-can listener -> `await server.async_setValues` on a pymodbus server "
            "(SimDevice) and a raw `put` on a Zenoh publisher. p50/p99 per window; the table "
            "gives their median and spread over the windows."
        ),
    )
    cfg = bench_config([bench_node("n1", 1)], "latency")
    inj = Injector(cfg.can.channel)
    gw = await start_gateway(cfg, inj, [1])
    assert gw.zenoh is not None and gw.modbus is not None
    bare = BarePipeline(unique_channel("latency-bare"))
    await bare.start()
    bare_inj = Injector(bare.channel)
    gw_key = f"{gw.zenoh.prefix}/n1/value/position"
    sub = start_subscriber(
        [zenoh_endpoint(cfg), bare.zenoh_endpoint], [(gw_key, "record"), (BARE_KEY, "record")]
    )
    poller = start_poller()
    parse = ["json", "i32"]
    res: dict[str, list[float]] = {k: [] for k in (
        "gw_mb_p50", "gw_mb_p99", "bare_mb_p50", "bare_mb_p99",
        "gw_z_p50", "gw_z_p99", "bare_z_p50", "bare_z_p99",
    )}  # fmt: skip
    pooled: dict[str, list[float]] = {"gw_mb": [], "bare_mb": [], "gw_z": [], "bare_z": []}
    unseen = {"gw_mb": 0, "bare_mb": 0, "gw_z": 0, "bare_z": 0}
    polls = {"gw": 0.0, "bare": 0.0}
    rtt: dict[str, list[float]] = {"gw_50": [], "gw_99": [], "bare_50": [], "bare_99": []}
    try:
        # make sure the subscriber is matched to both publishers before measuring
        for pipeline_inj in (inj, bare_inj):
            for k in range(200):
                pipeline_inj.send_direct(can.Message(arbitration_id=TPDO1_BASE + 1,
                                                     data=SGH10_TPDO.pack(-1 - k, 7),
                                                     is_extended_id=False))  # fmt: skip
                if await sub.acall("wait", 1, 0.05, 0.05):
                    break
            await sub.acall("take", parse)
        value = 0
        for _rep in range(reps):
            for name, port, pin in (
                ("gw", gw.modbus.port, inj),
                ("bare", bare.modbus_port, bare_inj),
            ):
                poll = asyncio.ensure_future(
                    poller.acall("poll", "127.0.0.1", port, 1, POSITION_REGISTER, 2, window_s + 0.4)
                )
                await asyncio.sleep(0.2)  # the poller is connected and polling
                sent = await asyncio.to_thread(_paced_send, pin, 1, value, window_s)
                value += len(sent) + 10
                polled = await poll
                await sub.acall("wait", len(sent), 0.3, 5.0)
                z = await sub.acall("take", parse)
                mb_seen: dict[int, float] = {}
                for regs, t in polled["changes"]:
                    mb_seen.setdefault(value_of(regs), t)
                idx = 0 if name == "gw" else 1
                z_seen: dict[int, float] = {}
                for i, v, t in z["records"]:
                    if i == idx:
                        z_seen.setdefault(round(v / POSITION_SCALE) if name == "gw" else v, t)
                polls[name] += polled["polls"] / polled["duration_s"]
                rtt[f"{name}_50"].append(polled["rtt_ms"][50])
                rtt[f"{name}_99"].append(polled["rtt_ms"][99])
                for kind, seen in (("mb", mb_seen), ("z", z_seen)):
                    lat = latencies_ms(sent, seen)
                    unseen[f"{name}_{kind}"] += len(sent) - len(lat)
                    pooled[f"{name}_{kind}"] += lat
                    res[f"{name}_{kind}_p50"].append(percentile(lat, 50))
                    res[f"{name}_{kind}_p99"].append(percentile(lat, 99))
    finally:
        poller.close()
        sub.close()
        inj.close()
        bare_inj.close()
        await bare.stop()
        await gw.stop()

    s = Summary.of
    rows = []
    for kind, label in (("mb", "Modbus"), ("z", "Zenoh")):
        for q in ("p50", "p99"):
            g, b = res[f"gw_{kind}_{q}"], res[f"bare_{kind}_{q}"]
            ratio = s(paired_ratios(g, b))
            if q == "p99":
                rows.append(Row(f"{label} {q} (ms)", s(g), "bare pipeline", s(b), ratio,
                                "<= 1 ms", s(g).median <= 1.0, digits=3))  # fmt: skip
                rows.append(Row(f"{label} {q}, ratio to bare", s(g), "bare pipeline", s(b),
                                ratio, "<= 1.2x bare", ratio.median <= 1.2, digits=3))  # fmt: skip
            else:
                rows.append(Row(f"{label} {q} (ms)", s(g), "bare pipeline", s(b), ratio, digits=3))
    for q in ("50", "99"):
        g, b = rtt[f"gw_{q}"], rtt[f"bare_{q}"]
        rows.append(Row(f"Modbus request round trip p{q} of the polling client (ms)", s(g),
                        "bare pipeline", s(b), s(paired_ratios(g, b)), digits=3))  # fmt: skip
    sec.rows = rows
    for key, lat in pooled.items():
        if lat:
            sec.notes.append(
                f"{key} pooled over all windows: {len(lat):,} samples, p50 "
                f"{percentile(lat, 50):.3f} ms, p90 {percentile(lat, 90):.3f} ms, p99 "
                f"{percentile(lat, 99):.3f} ms, max {max(lat):.3f} ms; values never seen: "
                f"{unseen[key]}."
            )
    sec.notes.append(
        f"Polling rate of the Modbus client: gateway {polls['gw'] / reps:,.0f} req/s, bare "
        f"{polls['bare'] / reps:,.0f} req/s (a value is seen at the first poll after it lands)."
    )
    return sec
