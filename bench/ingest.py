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


async def run(reps: int = 5, n_frames: int = 20_000) -> Section:
    sec = Section(
        key="ingest",
        title="1. Ingest: TPDO frames/s through the gateway",
        method=(
            f"{n_frames:,} SGH10 TPDO1 frames (6 bytes, distinct positions) per run, {reps} "
            "repetitions, gateway and bare listener alternating. Gateway: decode -> process "
            "image -> Zenoh publication of both signals (`publish: every`), clock stopped when "
            "the last frame is published; a Zenoh subscriber in another process (TCP loopback) "
            "counts every position, a Modbus read checks the last one. Baseline: python-can "
            "listener thread, `recv` + `struct.unpack_from` into a dict. Injection from a "
            "third Bus in its own thread, straight into the receive queue (no copy) unless "
            "said otherwise."
        ),
    )
    cfg = bench_config([bench_node("n1", 1)], "ingest")
    inj = Injector(cfg.can.channel)
    gw = await start_gateway(cfg, inj, [1])
    assert gw.zenoh is not None and gw.modbus is not None
    node = gw.image.nodes["n1"]
    pos_sig = node.signals["position"]
    gw_done = threading.Event()
    gw_state: dict[str, Any] = {"target": None, "done_at": 0.0}

    def last_frame_seen(n: Any, names: tuple[str, ...], ts: float) -> None:
        if n is node and pos_sig.value == gw_state["target"]:
            gw_state["done_at"] = time.perf_counter()
            gw_done.set()

    gw.image.value_listeners.append(last_frame_seen)  # after the Zenoh bridge's listener
    prefix = gw.zenoh.prefix
    pos_key = f"{prefix}/n1/value/position"
    vel_key = f"{prefix}/n1/value/velocity"
    sub = start_subscriber([zenoh_endpoint(cfg)], [(pos_key, "record"), (vel_key, "count")])
    bare_channel = unique_channel("ingest-bare")
    bare = BareListener(bare_channel)
    bare_inj = Injector(bare_channel)
    mb = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=2)
    await mb.connect()
    reader = gw.driver._thread
    assert reader is not None
    results: dict[str, list[float]] = {k: [] for k in (
        "bare", "gw", "gw_sub", "bare_send", "gw_send", "bare_cpu", "gw_cpu", "gw_proc_cpu",
    )}  # fmt: skip
    lost_total = vel_missing_total = 0
    modbus_ok = 0
    try:
        # warm up until the subscriber is matched (zenoh declares routes asynchronously)
        seed = -1_000_000
        for k in range(200):
            inj.send_direct(tpdo_frames(1, [seed - k])[0])
            got = await sub.acall("wait", 1, 0.05, 0.05)
            if got:
                break
        await asyncio.sleep(0.2)
        await sub.acall("take", ["json", "json"])
        base = 0
        for _rep in range(reps):
            for mode in ("send_direct", "send"):
                # --- baseline
                frames = tpdo_frames(1, range(base, base + n_frames))
                base += n_frames
                bare.target = (TPDO1_BASE + 1, base - 1)
                send = bare_inj.send_direct if mode == "send_direct" else bare_inj.send
                r = await _timed_run(send, frames, bare.done, lambda: bare.done_at, bare.thread)
                if mode == "send_direct":
                    results["bare"].append(r["fps"])
                    results["bare_cpu"].append(r["reader_cpu_us"])
                else:
                    results["bare_send"].append(r["fps"])
                # --- gateway
                frames = tpdo_frames(1, range(base, base + n_frames))
                first = base
                base += n_frames
                gw_state["target"] = base - 1
                send = inj.send_direct if mode == "send_direct" else inj.send
                r = await _timed_run(send, frames, gw_done, lambda: gw_state["done_at"], reader)
                got = await sub.acall("wait", n_frames, 1.0, 30.0)
                data = await sub.acall("take", ["json", "json"])
                seen = {round(v / POSITION_SCALE) for _, v, _ in data["records"]}
                lost = len(set(range(first, base)) - seen)
                lost_total += lost
                vel_missing_total += n_frames - data["counts"].get(vel_key, 0)
                rr = await mb.read_input_registers(100, count=2, device_id=1)
                if not rr.isError():
                    v = (rr.registers[0] << 16) | rr.registers[1]
                    v = v - (1 << 32) if v >= 1 << 31 else v
                    modbus_ok += v == base - 1
                if mode == "send_direct":
                    results["gw"].append(r["fps"])
                    results["gw_cpu"].append(r["reader_cpu_us"])
                    results["gw_proc_cpu"].append(r["process_cpu_us"])
                    last_t = max((t for _, _, t in data["records"]), default=float("nan"))
                    results["gw_sub"].append(n_frames / (last_t - r["t0"]) if got else float("nan"))
                else:
                    results["gw_send"].append(r["fps"])
        ceiling = [_injector_ceiling(n_frames) for _ in range(3)]
    finally:
        mb.close()
        sub.close()
        bare.close()
        bare_inj.close()
        await gw.stop()
        inj.close()

    s = Summary.of
    ratio = s(paired_ratios(results["gw"], results["bare"]))
    sec.rows = [
        Row("frames/s, decoded into the image and published", s(results["gw"]),
            "bare listener", s(results["bare"]), ratio, ">= 0.5x bare", ratio.median >= 0.5),
        Row("frames/s, same, vs a saturated 1 Mbit/s bus", s(results["gw"]),
            "8,900 frames/s", s([SATURATED_BUS_FPS]),
            s([x / SATURATED_BUS_FPS for x in results["gw"]]), ">= 10x bus",
            s(results["gw"]).median >= 10 * SATURATED_BUS_FPS),
        Row("frames/s until the subscriber has the last sample", s(results["gw_sub"]),
            "bare listener", s(results["bare"]), s(paired_ratios(results["gw_sub"], results["bare"]))),
        Row("frames/s with python-can `send` injection (deep copy)", s(results["gw_send"]),
            "bare listener, same injection", s(results["bare_send"]),
            s(paired_ratios(results["gw_send"], results["bare_send"]))),
        Row("reader-thread CPU per frame (us)", s(results["gw_cpu"]), "bare listener thread",
            s(results["bare_cpu"]), s(paired_ratios(results["gw_cpu"], results["bare_cpu"])), digits=1),
        Row("whole-process CPU per frame, injector excluded (us)", s(results["gw_proc_cpu"]),
            digits=1),
        Row("injector ceiling, python-can `send` (frames/s)", s([c["send"] for c in ceiling])),
        Row("injector ceiling, `send_direct` (frames/s)", s([c["send_direct"] for c in ceiling])),
        Row("position updates lost at the Zenoh subscriber (all runs)", s([lost_total]),
            target="0", met=lost_total == 0),
        Row("velocity samples missing at the Zenoh subscriber (all runs)", s([vel_missing_total]),
            target="0", met=vel_missing_total == 0),
        Row(f"Modbus image holds the last value (runs of {2 * reps})", s([modbus_ok]),
            target=f"{2 * reps}", met=modbus_ok == 2 * reps),
    ]  # fmt: skip
    cpu_gw = s(results["gw_cpu"]).median
    sec.notes.append(
        f"Reader-thread capacity from its CPU time alone: about {1e6 / cpu_gw:,.0f} frames/s for "
        f"the gateway against {1e6 / s(results['bare_cpu']).median:,.0f} for the bare listener "
        "(what each could do with a core of its own and a free injector)."
    )
    return sec
