"""Benchmark 10, floors: what the gateway's dependencies cost alone, so that a figure of
sections 8 and 9 can be read against what no code of ours could go below.

- **Zenoh put**: a process of its own (one Python thread, nothing else busy) puts JSON samples
  of a value's size on 120 keys at 16,000 puts/s (the value samples per second of the 1 Mbit/s
  scenario of section 9), with a Zenoh timestamp as the gateway does, in bursts of 10 and of 1
  put per wake-up; a subscriber in another process (TCP loopback) takes every sample. Figure:
  CPU of the putting process (all its threads: Python and Zenoh's) per put.
- **Modbus request**: the PLC of sections 8 and 9 (pymodbus client in its own process; 6 units,
  16 registers at 0 and 3 at 100 every 10 ms: 1,200 requests/s) against the gateway's Modbus
  server (one started gateway, 6 SGH10 nodes with one TPDO each, on a virtual bus) and against
  a bare asyncio protocol on the same event loop that answers each read with canned registers
  (no register map, no image). Figure: CPU of the event loop thread per request (a window with
  the PLC minus a window without it, each request answered and counted).

Imports: bench.*, gateway (through bench.rig), zenoh (in the child), the standard library.
"""

from __future__ import annotations

import asyncio
import os
import time
from typing import Any

from bench.linerate import PLC_BLOCKS, PLC_NODES, PLC_PERIOD_S, PlcClient
from bench.pipeline import BareModbus
from bench.report import Row, Section
from bench.rig import (
    Injector,
    bench_config,
    bench_node,
    free_port,
    start_gateway,
    tpdo_frames,
    wait_until,
)
from bench.stats import Summary
from bench.workers import Worker, start_subscriber

PUT_RATE = 16_000
PUT_KEYS = 120
#: the size of a value sample's JSON (``payloads.value_json``: value, raw, unit, quality, times)
PAYLOAD = (
    b'{"value":1234.5,"raw":12345,"unit":"mm","quality":"good",'
    b'"ts":"2026-11-26T18:14:00.123456Z","age_ms":0}'
)
PLC_REQUESTS_PER_S = PLC_NODES * len(PLC_BLOCKS) / PLC_PERIOD_S


class ZenohPutter:
    """Worker: a Zenoh session listening on ``endpoint`` with ``PUT_KEYS`` publishers."""

    def __init__(self, endpoint: str) -> None:
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.pubs = [self.session.declare_publisher(f"floor/n{i}/value/x") for i in range(PUT_KEYS)]
        self.info = {"keys": PUT_KEYS}

    def run(self, burst: int, rate: float, duration_s: float) -> dict[str, float]:
        """Put at ``rate`` in bursts of ``burst``, sleeping between bursts; process CPU."""
        pubs, session, n = self.pubs, self.session, 0
        clock = time.perf_counter
        t = os.times()
        c0, t0 = t.user + t.system, clock()
        end = t0 + duration_s
        while clock() < end:
            for k in range(burst):
                pubs[(n + k) % PUT_KEYS].put(PAYLOAD, timestamp=session.new_timestamp())
            n += burst
            delay = t0 + n / rate - clock()
            if delay > 0:
                time.sleep(delay)
        t = os.times()
        wall = clock() - t0
        return {"puts": n, "cpu_s": t.user + t.system - c0, "wall_s": wall}

    def close(self) -> None:
        self.session.close()


async def _loop_cpu(duration_s: float) -> float:
    """CPU of the event loop's thread over ``duration_s`` (measured on that thread)."""
    c0 = time.thread_time()
    await asyncio.sleep(duration_s)
    return time.thread_time() - c0


async def _per_request_us(port: int, count: Any, window_s: float) -> float:
    """Loop-thread CPU per PLC request against ``port``: a window with the PLC minus one
    without it; the PLC's requests all answered (an error raises)."""
    idle = await _loop_cpu(window_s)
    plc = Worker(PlcClient, name="plc")
    try:
        before = count()
        units = list(range(1, PLC_NODES + 1))
        call = asyncio.ensure_future(
            plc.acall("run", port, units, PLC_BLOCKS, PLC_PERIOD_S, window_s + 0.6,
                      timeout_s=window_s + 60)
        )  # fmt: skip
        await asyncio.sleep(0.3)
        busy = await _loop_cpu(window_s)
        result = await call
    finally:
        plc.close()
    if result["errors"]:
        raise RuntimeError(f"the PLC's reads failed: {result['errors']} of {result['requests']}")
    served = count() - before
    rps = served / (window_s + 0.6)
    return (busy - idle) / window_s / rps * 1e6


async def _modbus_floor(reps: int, window_s: float) -> tuple[list[float], list[float]]:
    cfg = bench_config([bench_node(f"n{i}", i) for i in range(1, PLC_NODES + 1)], "floors")
    inj = Injector(cfg.can.channel)
    gw = await start_gateway(cfg, inj, range(1, PLC_NODES + 1))
    canned = [0]
    server = None
    try:
        for i in range(1, PLC_NODES + 1):
            inj.send(tpdo_frames(i, [1000 + i])[0])  # a value for the reads at 100
        assert gw.modbus is not None
        store = gw.modbus.store
        await wait_until(
            lambda: all(n.snapshot()["position"].seq for n in gw.image.nodes.values()),
            5.0,
            "the nodes' TPDOs in the image",
        )
        loop = asyncio.get_running_loop()
        server = await loop.create_server(lambda: BareModbus(canned), "127.0.0.1", 0)
        bare_port = server.sockets[0].getsockname()[1]
        gw_port = cfg.modbus.port
        gw_us, bare_us = [], []
        for _ in range(reps):
            bare_us.append(await _per_request_us(bare_port, lambda: canned[0], window_s))
            gw_us.append(await _per_request_us(gw_port, lambda: store.requests, window_s))
        return gw_us, bare_us
    finally:
        if server is not None:
            server.close()
        await gw.stop()
        inj.close()


def _received(sub: Worker, expected: int, quiet_s: float = 0.5) -> int:
    """Samples the subscriber took since the last call: until ``expected`` or none came for
    ``quiet_s`` (those still in flight when a run ends arrive after it)."""
    got, last, t_last = 0, -1, time.monotonic()
    while got < expected and time.monotonic() - t_last < quiet_s:
        got += sum(sub.call("take", ["json"])["counts"].values())
        if got != last:
            last, t_last = got, time.monotonic()
        time.sleep(0.02)
    return got


def _zenoh_floor(reps: int, duration_s: float) -> dict[int, list[dict[str, float]]]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    putter = Worker(ZenohPutter, endpoint, name="zenoh-putter")
    sub = None
    try:
        sub = start_subscriber([endpoint], [("floor/**", "count")])
        warm = putter.call("run", 10, PUT_RATE, 1.0, timeout_s=60)  # the subscriber matched
        _received(sub, warm["puts"])
        runs: dict[int, list[dict[str, float]]] = {10: [], 1: []}
        for _ in range(reps):
            for burst in runs:
                r = putter.call("run", burst, PUT_RATE, duration_s, timeout_s=duration_s + 60)
                r["received"] = _received(sub, r["puts"])
                runs[burst].append(r)
        return runs
    finally:
        putter.close()
        if sub is not None:
            sub.close()


async def run(reps: int = 3, window_s: float = 3.0) -> Section:
    sec = Section(
        key="floors",
        title="10. Floors: what the dependencies cost alone",
        method=(
            f"**Zenoh put**: one Python thread in a process of its own puts a value-sized JSON "
            f"sample with a Zenoh timestamp on {PUT_KEYS} keys at {PUT_RATE:,} puts/s (the value "
            "samples/s of section 9's 1 Mbit/s scenario), in bursts of 10 and of 1 per wake-up; "
            "a subscriber in another process takes every sample. CPU of the putting process "
            f"(all threads) per put, {reps} runs of {window_s:g} s each. **Modbus request**: "
            f"the PLC of sections 8-9 ({PLC_REQUESTS_PER_S:,.0f} requests/s from a pymodbus "
            "client process: 16 registers at 0 and 3 at 100 of 6 units) against the gateway's "
            "server (6 SGH10 nodes, values in the image) and against a bare asyncio protocol "
            "on the same event loop answering canned registers; CPU of the loop thread per "
            f"request (a {window_s:g} s window with the PLC minus one without), {reps} "
            "alternating pairs."
        ),
    )
    zruns = await asyncio.to_thread(_zenoh_floor, reps, window_s)
    gw_us, bare_us = await _modbus_floor(reps, window_s)
    s = Summary.of
    for burst, runs in zruns.items():
        per_put = [r["cpu_s"] / r["puts"] * 1e6 for r in runs]
        sec.rows.append(Row(f"Zenoh put, bursts of {burst}: process CPU per put (us)", s(per_put),
                            digits=1))  # fmt: skip
        sec.rows.append(Row(f"Zenoh put, bursts of {burst}: samples not received",
                            s([r["puts"] - r["received"] for r in runs]), target="0",
                            met=all(r["puts"] == r["received"] for r in runs)))  # fmt: skip
    ratios = [g / b for g, b in zip(gw_us, bare_us, strict=True) if b > 0]
    sec.rows.append(Row("Modbus request: event loop CPU per request (us)", s(gw_us),
                        "bare asyncio protocol", s(bare_us), s(ratios), digits=1))  # fmt: skip
    put10 = s([r["cpu_s"] / r["puts"] * 1e6 for r in zruns[10]]).median
    sec.notes.append(
        f"At {PUT_RATE:,} value samples/s, Zenoh alone takes {put10 * PUT_RATE / 1e4:.1f}% of "
        f"one core in bursts of 10; the bare asyncio protocol answers the PLC's "
        f"{PLC_REQUESTS_PER_S:,.0f} requests/s with "
        f"{s(bare_us).median * PLC_REQUESTS_PER_S / 1e4:.1f}% of a core. Added to the bare "
        "listener's share in section 9, that is the least a gateway built on these libraries "
        "spends on that scenario before decoding a frame (see the findings)."
    )
    return sec


def _main() -> None:
    sec = asyncio.run(run())
    for row in sec.rows:
        print(row.figure, row.value, row.baseline, row.ratio)
    print(*sec.notes, sep="\n")


if __name__ == "__main__":
    _main()
