"""Benchmark 1, ingest: TPDO frames/s through the whole gateway against a bare listener.

The gateway (one SGH10 node, Zenoh ``publish: every``) receives N TPDOs with distinct positions
from an injector Bus on its virtual channel: reader thread -> decode -> process image -> two
Zenoh publications per frame. The clock runs from the first frame sent to the moment the last
frame's value is in the image and published (a value listener placed after the Zenoh bridge's);
a Zenoh subscriber in another process, connected over TCP loopback, must see every position,
and a Modbus read after each run must return the last one.

The baseline is a bare python-can listener on its own virtual channel (a second Bus; the same
injector code sends on a third), whose thread does only ``recv`` + ``struct.unpack_from`` into a
dict + the same last-frame check. Runs of the two alternate, repetition by repetition.

Injection: ``send_direct`` (frames straight into the receiving queues) is the headline, because
python-can's virtual ``send`` deep-copies every message (a cost real CAN backends do not have);
runs with ``send`` are reported too, as is the injector's own ceiling for both.

Imports: bench.*, gateway (through bench.rig), python-can, pymodbus client.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from typing import Any

import can
from pymodbus.client import AsyncModbusTcpClient

from bench.report import Row, Section
from bench.rig import (
    SGH10_TPDO,
    TPDO1_BASE,
    Injector,
    bench_config,
    bench_node,
    start_gateway,
    tpdo_frames,
    unique_channel,
    zenoh_endpoint,
)
from bench.stats import Summary, paired_ratios
from bench.workers import start_subscriber
from canopen_gateway.northbound.keys import pdo_key

SATURATED_BUS_FPS = 8_900  # 1 Mbit/s CAN, 8-byte data frames incl. stuffing (issue text)
POSITION_SCALE = 0.1  # SGH10 profile: position in 0.1 mm steps


def thread_cpu_s(thread: threading.Thread) -> float:
    """CPU seconds used so far by one thread (Linux per-thread CPU clock)."""
    assert thread.ident is not None
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


class BareListener:
    """The baseline: a python-can listener thread doing only struct.unpack_from into a dict."""

    def __init__(self, channel: str):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.values: dict[int, tuple[int, ...]] = {}
        self.target: tuple[int, int] | None = None  # (cob_id, position of the last frame)
        self.done = threading.Event()
        self.done_at = 0.0
        self._running = True
        self.thread = threading.Thread(target=self._run, name="bare-listener", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        recv = self.bus.recv
        unpack = SGH10_TPDO.unpack_from
        values = self.values
        clock = time.perf_counter
        while self._running:
            msg = recv(0.05)
            if msg is None:
                continue
            vals = unpack(msg.data)
            values[msg.arbitration_id] = vals
            if self.target is not None and vals[0] == self.target[1]:
                self.done_at = clock()
                self.done.set()

    def close(self) -> None:
        self._running = False
        self.thread.join(2.0)
        self.bus.shutdown()


def _send_all(send: Callable[[can.Message], None], frames: list[can.Message]) -> float:
    t0 = time.perf_counter()
    for m in frames:
        send(m)
    return t0


async def _timed_run(
    inject: Callable[[can.Message], None],
    frames: list[can.Message],
    done: threading.Event,
    done_at: Callable[[], float],
    thread: threading.Thread,
) -> dict[str, float]:
    """Send frames from an injector thread; frames/s until the last one is processed."""
    done.clear()
    cpu0 = thread_cpu_s(thread)
    proc0 = time.process_time()
    injector_cpu: list[float] = []

    def injector() -> float:
        c0 = time.thread_time()
        t0 = _send_all(inject, frames)
        injector_cpu.append(time.thread_time() - c0)
        return t0

    t0 = await asyncio.to_thread(injector)
    if not await asyncio.to_thread(done.wait, 60.0):
        raise TimeoutError("last frame not processed within 60 s")
    elapsed = done_at() - t0
    n = len(frames)
    return {
        "fps": n / elapsed,
        "t0": t0,
        "reader_cpu_us": (thread_cpu_s(thread) - cpu0) / n * 1e6,
        "process_cpu_us": (time.process_time() - proc0 - injector_cpu[0]) / n * 1e6,
    }


def _injector_ceiling(n: int) -> dict[str, float]:
    """Frames/s the injector alone reaches into one receiver that does not read."""
    channel = unique_channel("ceiling")
    idle = can.Bus(interface="virtual", channel=channel)
    inj = Injector(channel)
    frames = tpdo_frames(1, range(n))
    out = {}
    try:
        for mode, send in (("send", inj.send), ("send_direct", inj.send_direct)):
            t0 = time.perf_counter()
            for m in frames:
                send(m)
            out[mode] = n / (time.perf_counter() - t0)
            while idle.recv(0) is not None:
                pass
    finally:
        inj.close()
        idle.shutdown()
    return out


class GatewayUnderTest:
    """A started gateway with one node, the hook that stops the clock, and its Modbus client."""

    def __init__(self, label: str, cfg: Any, sub_index: int, parse: str):
        self.label = label
        self.cfg = cfg
        self.sub_index = sub_index  # the subscription that records this gateway's positions
        self.parse = parse
        self.done = threading.Event()
        self.target: int | None = None
        self.done_at = 0.0

    async def start(self) -> None:
        self.inj = Injector(self.cfg.can.channel)
        self.gw = await start_gateway(self.cfg, self.inj, [1])
        assert self.gw.zenoh is not None and self.gw.modbus is not None
        node = self.gw.image.nodes["n1"]

        def last_frame_seen(n: Any, names: tuple[str, ...], ts: float) -> None:
            if n is node and node.signals["position"].value == self.target:
                self.done_at = time.perf_counter()
                self.done.set()

        # value listeners run in order: this one after the Zenoh bridge's; with raw PDO
        # publication the put comes after the image update, so the clock stops just before it
        self.gw.image.value_listeners.append(last_frame_seen)
        self.reader = self.gw.driver._thread
        self.mb = AsyncModbusTcpClient("127.0.0.1", port=self.gw.modbus.port, timeout=2)
        await self.mb.connect()

    async def modbus_position(self) -> int | None:
        rr = await self.mb.read_input_registers(100, count=2, device_id=1)
        if rr.isError():
            return None
        v = (rr.registers[0] << 16) | rr.registers[1]
        return v - (1 << 32) if v >= 1 << 31 else v

    async def stop(self) -> None:
        self.mb.close()
        await self.gw.stop()
        self.inj.close()


async def run(
    reps: int = 5, n_frames: int = 20_000, zenoh_json5: dict[str, Any] | None = None
) -> Section:
    sec = Section(
        key="ingest",
        title="1. Ingest: TPDO frames/s through the gateway",
        method=(
            f"{n_frames:,} SGH10 TPDO1 frames (6 bytes, distinct positions) per run, {reps} "
            "repetitions, bare listener and gateways alternating. Gateway: decode -> process "
            "image -> Zenoh publication of both signals as JSON (`publish: every`), clock "
            "stopped when the last frame is published; a Zenoh subscriber in another process "
            "(TCP loopback) counts every position, a Modbus read checks the last one. Variant "
            "**raw PDO**: the same with `zenoh.raw_pdo: true` and the JSON value publication "
            "off for both signals (one `put` of the frame's bytes per frame). Baseline: "
            "python-can listener thread, `recv` + `struct.unpack_from` into a dict. Injection "
            "from a third Bus in its own thread, straight into the receive queue (no copy) "
            "unless said otherwise."
        ),
    )
    extra: dict[str, Any] = {"json5": zenoh_json5} if zenoh_json5 else {}
    off = {"position": {"publish": "off"}, "velocity": {"publish": "off"}}
    json_gw = GatewayUnderTest(
        "json", bench_config([bench_node("n1", 1)], "ingest", zenoh=extra), 0, "json"
    )
    raw_gw = GatewayUnderTest(
        "raw",
        bench_config(
            [bench_node("n1", 1, signals=off)], "ingest-raw", zenoh={"raw_pdo": True, **extra}
        ),
        2,
        "i32",
    )
    await json_gw.start()
    await raw_gw.start()
    assert json_gw.gw.zenoh is not None and raw_gw.gw.zenoh is not None
    prefix = json_gw.gw.zenoh.prefix
    vel_key = f"{prefix}/n1/value/velocity"
    subs = [
        (f"{prefix}/n1/value/position", "record"),
        (vel_key, "count"),
        (pdo_key(raw_gw.gw.zenoh.prefix, "n1", TPDO1_BASE + 1), "record"),
    ]
    parse = ["json", "json", "i32"]
    sub = start_subscriber([zenoh_endpoint(json_gw.cfg), zenoh_endpoint(raw_gw.cfg)], subs)
    bare_channel = unique_channel("ingest-bare")
    bare = BareListener(bare_channel)
    bare_inj = Injector(bare_channel)
    results: dict[str, list[float]] = {}
    lost = {"json": 0, "raw": 0}
    vel_missing_total = 0
    modbus_ok = {"json": 0, "raw": 0}
    runs = {"json": 0, "raw": 0}

    def add(key: str, value: float) -> None:
        results.setdefault(key, []).append(value)

    try:
        # warm up until the subscriber is matched (zenoh declares routes asynchronously)
        for g in (json_gw, raw_gw):
            for k in range(200):
                g.inj.send_direct(tpdo_frames(1, [-1_000_000 - k])[0])
                recs = (await sub.acall("take", parse))["records"]
                if any(i == g.sub_index for i, _, _ in recs):
                    break
                await asyncio.sleep(0.02)
        await asyncio.sleep(0.2)
        await sub.acall("take", parse)
        base = 0
        plan = [("bare", "send_direct"), ("json", "send_direct"), ("raw", "send_direct"),
                ("bare", "send"), ("json", "send")]  # fmt: skip
        for _rep in range(reps):
            for who, mode in plan:
                frames = tpdo_frames(1, range(base, base + n_frames))
                first = base
                base += n_frames
                key = who if mode == "send_direct" else f"{who}_send"
                if who == "bare":
                    bare.target = (TPDO1_BASE + 1, base - 1)
                    send = bare_inj.send_direct if mode == "send_direct" else bare_inj.send
                    r = await _timed_run(send, frames, bare.done, lambda: bare.done_at, bare.thread)
                    add(key, r["fps"])
                    add(f"{key}_cpu", r["reader_cpu_us"])
                    continue
                g = json_gw if who == "json" else raw_gw
                assert g.reader is not None
                g.target = base - 1
                send = g.inj.send_direct if mode == "send_direct" else g.inj.send
                r = await _timed_run(send, frames, g.done, lambda g=g: g.done_at, g.reader)
                got = await sub.acall("wait", n_frames, 1.0, 30.0)
                data = await sub.acall("take", parse)
                mine = [(v, t) for i, v, t in data["records"] if i == g.sub_index]
                seen = {round(v / POSITION_SCALE) if g.parse == "json" else v for v, _ in mine}
                lost[who] += len(set(range(first, base)) - seen)
                runs[who] += 1
                if who == "json":
                    vel_missing_total += n_frames - data["counts"].get(vel_key, 0)
                modbus_ok[who] += await g.modbus_position() == base - 1
                add(key, r["fps"])
                add(f"{key}_cpu", r["reader_cpu_us"])
                add(f"{key}_proc_cpu", r["process_cpu_us"])
                last_t = max((t for _, t in mine), default=float("nan"))
                add(f"{key}_sub", n_frames / (last_t - r["t0"]) if got else float("nan"))
        ceiling = [_injector_ceiling(n_frames) for _ in range(3)]
    finally:
        sub.close()
        bare.close()
        bare_inj.close()
        await json_gw.stop()
        await raw_gw.stop()

    s = Summary.of
    ratio = s(paired_ratios(results["json"], results["bare"]))
    raw_ratio = s(paired_ratios(results["raw"], results["bare"]))
    bus = [SATURATED_BUS_FPS] * reps
    sec.rows = [
        Row("frames/s, decoded into the image and published as JSON", s(results["json"]),
            "bare listener", s(results["bare"]), ratio, ">= 0.5x bare", ratio.median >= 0.5),
        Row("frames/s, JSON, against a saturated 1 Mbit/s bus", s(results["json"]),
            "8,900 frames/s", s([SATURATED_BUS_FPS]), s(paired_ratios(results["json"], bus)),
            ">= 10x bus", s(results["json"]).median >= 10 * SATURATED_BUS_FPS),
        Row("frames/s until the subscriber has the last JSON sample", s(results["json_sub"]),
            "bare listener", s(results["bare"]), s(paired_ratios(results["json_sub"], results["bare"]))),
        Row("raw PDO variant: frames/s, decoded into the image, bytes published", s(results["raw"]),
            "bare listener", s(results["bare"]), raw_ratio, ">= 0.5x bare", raw_ratio.median >= 0.5),
        Row("raw PDO variant: against a saturated 1 Mbit/s bus", s(results["raw"]),
            "8,900 frames/s", s([SATURATED_BUS_FPS]), s(paired_ratios(results["raw"], bus)),
            ">= 10x bus", s(results["raw"]).median >= 10 * SATURATED_BUS_FPS),
        Row("raw PDO variant: frames/s until the subscriber has the last frame", s(results["raw_sub"]),
            "bare listener", s(results["bare"]), s(paired_ratios(results["raw_sub"], results["bare"]))),
        Row("JSON, python-can `send` injection (deep copy): frames/s", s(results["json_send"]),
            "bare listener, same injection", s(results["bare_send"]),
            s(paired_ratios(results["json_send"], results["bare_send"]))),
        Row("reader-thread CPU per frame, JSON (us)", s(results["json_cpu"]), "bare listener thread",
            s(results["bare_cpu"]), s(paired_ratios(results["json_cpu"], results["bare_cpu"])), digits=1),
        Row("reader-thread CPU per frame, raw PDO (us)", s(results["raw_cpu"]), "bare listener thread",
            s(results["bare_cpu"]), s(paired_ratios(results["raw_cpu"], results["bare_cpu"])), digits=1),
        Row("whole-process CPU per frame, JSON, injector excluded (us)", s(results["json_proc_cpu"]),
            digits=1),
        Row("injector ceiling, python-can `send` (frames/s)", s([c["send"] for c in ceiling])),
        Row("injector ceiling, `send_direct` (frames/s)", s([c["send_direct"] for c in ceiling])),
        Row(f"JSON: position updates lost at the subscriber ({runs['json']} runs)", s([lost["json"]]),
            target="0", met=lost["json"] == 0),
        Row(f"JSON: velocity samples missing at the subscriber ({runs['json']} runs)",
            s([vel_missing_total]), target="0", met=vel_missing_total == 0),
        Row(f"raw PDO: frames lost at the subscriber ({runs['raw']} runs)", s([lost["raw"]]),
            target="0", met=lost["raw"] == 0),
        Row("Modbus image holds the last value (runs, JSON + raw)",
            s([modbus_ok["json"] + modbus_ok["raw"]]), target=f"{runs['json'] + runs['raw']}",
            met=modbus_ok["json"] + modbus_ok["raw"] == runs["json"] + runs["raw"]),
    ]  # fmt: skip
    for key, label in (("json", "JSON"), ("raw", "raw PDO")):
        sec.notes.append(
            f"{label}: reader-thread capacity from its CPU time alone about "
            f"{1e6 / s(results[f'{key}_cpu']).median:,.0f} frames/s, bare listener "
            f"{1e6 / s(results['bare_cpu']).median:,.0f} (what each could do with a core of its "
            "own and a free injector)."
        )
    return sec
