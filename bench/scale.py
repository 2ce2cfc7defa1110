"""Benchmark 4, scale: 127 nodes, two TPDOs each every 10 ms (25,400 frames/s), for ~10 s.

The gateway runs in a process of its own (``ScaleGateway``, spawned), with a raw frame
generator thread in that process feeding its virtual channel straight into the receive queue:
every 1 ms slot sends the TPDOs due in it (TPDO1 of node n in slot n mod 10, TPDO2 five slots
later, so frames come spread like on a bus, not in 10 ms bursts), every node's heartbeat every
100 ms (the nodes are supervised: a late heartbeat would be a lost node), and one EMCY every
100 ms. The master sends SYNC every 10 ms. Each frame carries a new position, so Zenoh
(``publish: every``) publishes 2 values per frame.

Measured: the gateway's CPU (process CPU time / wall, the generator thread's own CPU taken
out), its resident memory (/proc VmRSS, VmHWM), lost events (frames not decoded, Zenoh samples
and EMCY events that did not arrive at a subscriber in another process, nodes that went lost),
and the latency of node 1's positions to a polling Modbus client and to the Zenoh subscriber,
per 2 s window. A second, shorter run tries the project's own simulator (``SimRunner`` with 127
``SimNode``) and reports the frame rate it reaches.

Imports: bench.*, gateway (through bench.rig; canopen_gateway.sim for the simulator run).
"""

from __future__ import annotations

import asyncio
import logging
import os
import struct
import tempfile
import threading
import time
from typing import Any

import can

from bench.machine import process_cpu_s, rss_kib, threads_cpu
from bench.report import Row, Section
from bench.rig import (
    NMT_EC_BASE,
    SGH10_TPDO,
    TPDO1_BASE,
    TPDO2_BASE,
    Injector,
    bench_config,
    bench_node,
    gateway_of,
    unique_channel,
    wait_until,
    zenoh_endpoint,
)
from bench.stats import Summary, percentile
from bench.workers import Worker, start_poller, start_subscriber

N_NODES = 127
POLL_FROM = 0.4  # share of a run before the Modbus client starts polling
PERIOD_MS = 10  # every node sends TPDO1 and TPDO2 once per period
HEARTBEAT_MS = 100  # SGH10 profile default (boot.heartbeat_ms)
EMCY_BASE = 0x080
EMCY_EVERY_MS = 100
EMCY_GENERIC = struct.pack("<HB5s", 0x1000, 0x01, b"\0" * 5)  # DS-301 generic error, reg. bit 0
POSITION_SCALE = 0.1


def _value_of(regs: tuple[int, ...]) -> int:
    v = (regs[0] << 16) | regs[1]
    return v - (1 << 32) if v >= 1 << 31 else v


class ScaleGateway:
    """Child process: the gateway with N nodes and the raw frame generator feeding it."""

    def __init__(self, n_nodes: int, sync_ms: int, publish: str, distinct_tpdo2: bool):
        # the gateway logs as `canopen-gateway run` does (warnings), to a file, not the terminal
        self.log_file = tempfile.NamedTemporaryFile(
            prefix="bench-scale-", suffix=".log", delete=False
        )
        logging.basicConfig(filename=self.log_file.name, level=logging.WARNING)
        self.rss_before = rss_kib()
        self.distinct_tpdo2 = distinct_tpdo2
        self.period_ms = sync_ms  # TPDO period = SYNC period
        nodes = [
            bench_node(f"n{i}", i, supervision="heartbeat", heartbeat_ms=HEARTBEAT_MS)
            for i in range(1, n_nodes + 1)
        ]
        # every node id is taken, so the gateway's own heartbeat producer is off
        self.cfg = bench_config(
            nodes, "scale", master={"heartbeat_ms": 0, "sync_period_ms": sync_ms},
            zenoh={"publish": publish},
        )  # fmt: skip
        self.n = n_nodes
        self.inj = Injector(self.cfg.can.channel)
        self.loading = False
        self.stop_gen = threading.Event()
        self.sent = {"tpdo": 0, "heartbeat": 0, "emcy": 0}
        self.probe: list[tuple[int, float]] = []
        self.windows: list[dict[str, float]] = []
        self.gen_cpu_s = 0.0
        self.max_lag_s = 0.0  # how late the generator ran behind its 1 ms slots
        self.loop = asyncio.new_event_loop()
        self.loop_thread = threading.Thread(
            target=self.loop.run_forever, name="gw-loop", daemon=True
        )
        self.loop_thread.start()
        t0 = time.perf_counter()
        self.gw = asyncio.run_coroutine_threadsafe(self._start(), self.loop).result(60)
        self.start_s = time.perf_counter() - t0
        self.rss_idle = rss_kib()
        assert self.gw.zenoh is not None and self.gw.modbus is not None
        self.info = {
            "modbus_port": self.gw.modbus.port,
            "endpoint": zenoh_endpoint(self.cfg),
            "prefix": self.gw.zenoh.prefix,
            "start_s": self.start_s,
        }

    async def _start(self) -> Any:
        gw = gateway_of(self.cfg, simulate=False)
        await gw.start()
        self.gen = threading.Thread(target=self._generate, name="generator", daemon=True)
        self.gen.start()
        await wait_until(
            lambda: all(n.operational() for n in gw.image.nodes.values()), 10.0, "nodes operational"
        )
        return gw

    # ------------------------------------------------------------------ generator thread
    def _generate(self) -> None:
        c0 = time.thread_time()
        put = self.inj.send_direct
        pack = SGH10_TPDO.pack
        clock = time.perf_counter
        ids = range(1, self.n + 1)
        period = self.period_ms
        tpdo1 = {k: [i for i in ids if i % period == k] for k in range(period)}
        tpdo2 = {k: [i for i in ids if (i + period // 2) % period == k] for k in range(period)}
        hb = {k: [i for i in ids if i % HEARTBEAT_MS == k] for k in range(HEARTBEAT_MS)}
        msg = can.Message
        for nid in ids:  # boot-up first: the master then does not probe the nodes by SDO
            put(msg(arbitration_id=NMT_EC_BASE + nid, data=b"\x00", is_extended_id=False))
        slot = 0
        nxt = clock()
        while not self.stop_gen.is_set():
            k = slot % period
            cycle = slot // period
            now_wall = time.time()
            for nid in hb[slot % HEARTBEAT_MS]:
                put(
                    msg(
                        arbitration_id=NMT_EC_BASE + nid,
                        data=b"\x05",
                        is_extended_id=False,
                        timestamp=now_wall,
                    )
                )
                self.sent["heartbeat"] += 1
            if self.loading:
                v2 = 2 * cycle + 1 if self.distinct_tpdo2 else 2 * cycle
                for base, slots, value in ((TPDO1_BASE, tpdo1, 2 * cycle), (TPDO2_BASE, tpdo2, v2)):
                    for nid in slots[k]:
                        m = msg(
                            arbitration_id=base + nid,
                            data=pack(value, 7),
                            is_extended_id=False,
                            timestamp=now_wall,
                        )
                        if nid == 1 and (not self.probe or self.probe[-1][0] != value):
                            self.probe.append((value, clock()))  # first frame of each value
                        put(m)
                        self.sent["tpdo"] += 1
                if slot % EMCY_EVERY_MS == 0:
                    nid = 1 + (slot // EMCY_EVERY_MS) % self.n
                    put(
                        msg(
                            arbitration_id=EMCY_BASE + nid,
                            data=EMCY_GENERIC,
                            is_extended_id=False,
                            timestamp=now_wall,
                        )
                    )
                    self.sent["emcy"] += 1
            slot += 1
            nxt += 0.001
            delay = nxt - clock()
            if delay > 0:
                time.sleep(delay)
            elif self.loading:
                self.max_lag_s = max(self.max_lag_s, -delay)
            self.gen_cpu_s = time.thread_time() - c0

    # ------------------------------------------------------------------ commands
    def poke(self, value: int) -> None:
        """One TPDO1 of node 1 (to see that a subscriber is matched)."""
        self.inj.send_direct(
            can.Message(
                arbitration_id=TPDO1_BASE + 1, data=SGH10_TPDO.pack(value, 7), is_extended_id=False
            )
        )

    def load(self, duration_s: float, window_s: float) -> dict[str, Any]:
        gw = self.gw
        counters = gw.image.counters
        tids = {
            "reader": gw.driver._thread.native_id if gw.driver._thread else None,
            "event loop": self.loop_thread.native_id,
            "generator": self.gen.native_id,
        }
        names = {v: k for k, v in tids.items() if v is not None}
        threads0 = {t.tid: t for t in threads_cpu()}
        frames0 = counters["frames_in"]
        nodes = list(gw.image.nodes.values())
        seq0 = sum(n.signals["position"].seq for n in nodes)  # +1 per TPDO decoded
        emcy0 = sum(n.health.emcy_count for n in nodes)
        assert gw.zenoh is not None
        pub0, events0 = gw.zenoh.publications, gw.zenoh.events_sent
        losses0 = sum(n.health.loss_count for n in gw.image.nodes.values())
        rxq: Any = gw.driver.bus.queue  # type: ignore[union-attr]
        sent0 = dict(self.sent)
        self.probe.clear()
        t_start = time.perf_counter()
        mark = (t_start, process_cpu_s(), self.gen_cpu_s)
        self.loading = True
        end = t_start + duration_s
        while time.perf_counter() < end:
            time.sleep(min(window_s, max(0.0, end - time.perf_counter())))
            now = (time.perf_counter(), process_cpu_s(), self.gen_cpu_s)
            wall = now[0] - mark[0]
            self.windows.append({
                "t0": mark[0], "t1": now[0],
                "gw_cpu": (now[1] - mark[1] - (now[2] - mark[2])) / wall,
                "gen_cpu": (now[2] - mark[2]) / wall,
                "rss_kib": rss_kib()["VmRSS"],
                "backlog": rxq.qsize(),
            })  # fmt: skip
            mark = now
        self.loading = False
        wall = time.perf_counter() - t_start
        threads1 = threads_cpu()  # CPU of the load phase only
        load_sent = {k: self.sent[k] - sent0[k] for k in self.sent}
        deadline = time.perf_counter() + 30.0
        while rxq.qsize() > 0 and time.perf_counter() < deadline:
            time.sleep(0.01)
        drained_s = time.perf_counter() - t_start - wall
        time.sleep(0.05)  # the last frame taken from the queue is being handled
        sent = {k: self.sent[k] - sent0[k] for k in self.sent}
        per_thread: dict[str, float] = {}
        for t in threads1:
            before = threads0.get(t.tid)
            used = t.cpu_s - (before.cpu_s if before else 0.0)
            label = names.get(t.tid, t.name)
            per_thread[label] = per_thread.get(label, 0.0) + used
        publications = gw.zenoh.publications - pub0
        events = gw.zenoh.events_sent - events0
        return {
            "wall_s": wall,
            "drained_s": drained_s,
            "load_sent": load_sent,
            "sent": sent,
            "backlog_left": rxq.qsize(),
            "frames_in": counters["frames_in"] - frames0,
            "tpdos_decoded": sum(n.signals["position"].seq for n in nodes) - seq0,
            "emcy_decoded": sum(n.health.emcy_count for n in nodes) - emcy0,
            "decode_errors": counters["decode_errors"],
            "value_publications": publications,
            "generator_max_lag_s": self.max_lag_s,
            "event_publications": events,
            "losses": sum(n.health.loss_count for n in nodes) - losses0,
            "not_alive": sum(1 for n in nodes if not n.health.alive),
            "windows": self.windows,
            "probe": list(self.probe),
            "per_thread_cpu_s": per_thread,
            "rss": {"before_gateway": self.rss_before, "idle": self.rss_idle, "end": rss_kib()},
        }

    def close(self) -> None:
        self.stop_gen.set()
        self.gen.join(2.0)
        asyncio.run_coroutine_threadsafe(self.gw.stop(), self.loop).result(30)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.loop_thread.join(2.0)
        self.inj.close()
        logging.shutdown()
        os.unlink(self.log_file.name)


class SimRate:
    """Child process: how many frames/s the project's SimRunner reaches with N SimNodes."""

    info = None

    def measure(self, n_nodes: int, duration_s: float) -> dict[str, float]:
        from canopen_gateway.profiles import load_profile
        from canopen_gateway.sim.node import SimNode
        from canopen_gateway.sim.objects import PersistentStore
        from canopen_gateway.sim.runner import SimRunner

        channel = unique_channel("simrate")
        lp = load_profile("sgh10")
        nodes = []
        for i in range(1, n_nodes + 1):
            # stored ("save" 1010h), so that power-on loads them (a node.set() before power-on
            # is overwritten by the EDS defaults)
            store = PersistentStore(
                values={
                    (0x1800, 5): PERIOD_MS,  # TPDO1 event timer (SGH10 manual 4.7.2.13)
                    (0x6200, 0): PERIOD_MS,  # its mirror (4.7.2.31)
                    (0x1017, 0): HEARTBEAT_MS,
                }
            )
            nodes.append(SimNode(lp, i, store=store))
        sim_bus = can.Bus(interface="virtual", channel=channel)
        runner = SimRunner(sim_bus, nodes)
        master = can.Bus(interface="virtual", channel=channel)
        counted = {"frames": 0}
        stop = threading.Event()

        def count() -> None:
            while not stop.is_set():
                if master.recv(0.05) is not None:
                    counted["frames"] += 1

        def sync() -> None:
            nxt = time.perf_counter()
            while not stop.is_set():
                master.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
                nxt += PERIOD_MS / 1000.0
                time.sleep(max(0.0, nxt - time.perf_counter()))

        runner.start()
        for n in nodes:
            runner.call(lambda now, n=n: n.power_on(now))
        master.send(can.Message(arbitration_id=0x000, data=b"\x01\x00", is_extended_id=False))
        threads = [threading.Thread(target=f, daemon=True) for f in (count, sync)]
        for t in threads:
            t.start()
        time.sleep(1.0)  # boot-up, NMT start, first event timers
        c0 = counted["frames"]
        cpu0 = process_cpu_s()
        t0 = time.perf_counter()
        time.sleep(duration_s)
        wall = time.perf_counter() - t0
        frames = counted["frames"] - c0
        cpu = (process_cpu_s() - cpu0) / wall
        stop.set()
        runner.stop()
        for t in threads:
            t.join(1.0)
        sim_bus.shutdown()
        master.shutdown()
        return {
            "fps": frames / wall,
            "cpu": cpu,
            "error": repr(runner.error) if runner.error else "",
        }


def _latencies_ms(probe: list[tuple[int, float]], seen: dict[int, float]) -> list[float]:
    return [(seen[v] - t) * 1000.0 for v, t in probe if v in seen]


async def _scenario(
    label: str,
    publish: str,
    distinct_tpdo2: bool,
    period_ms: int,
    duration_s: float,
    window_s: float,
) -> tuple[list[Row], list[str]]:
    sg = Worker(ScaleGateway, N_NODES, period_ms, publish, distinct_tpdo2,
                name="scale-gateway", start_timeout_s=120)  # fmt: skip
    info = sg.info
    prefix = info["prefix"]
    probe_key = f"{prefix}/n1/value/position"
    sub = start_subscriber([info["endpoint"]], [(f"{prefix}/**", "count")], probe_key)
    poller = start_poller()
    try:
        for k in range(200):
            await sg.acall("poke", -1 - k)
            if await sub.acall("wait", 1, 0.05, 0.05):
                break
        sub0 = await sub.acall("take", ["json"])
        load = asyncio.ensure_future(
            sg.acall("load", duration_s, window_s, timeout_s=duration_s + 90)
        )
        # the first part of the load without a Modbus client, the rest with one polling
        await asyncio.sleep(duration_s * POLL_FROM)
        poll_start = time.perf_counter()
        poll_s = duration_s * (1 - POLL_FROM) - 0.2
        polled = await poller.acall("poll", "127.0.0.1", info["modbus_port"], 1, 100, 2, poll_s)
        poll_end = poll_start + poll_s
        result = await load
        await sub.acall("wait", 10**9, 1.0, 15.0)
        z = await sub.acall("take", ["json"])
    finally:
        poller.close()
        sub.close()
        sg.close()

    counts: dict[str, int] = z["counts"]
    value_samples = sum(v for k, v in counts.items() if "/value/" in k)
    emcy_samples = sum(v for k, v in counts.items() if k.endswith("/emcy"))
    state_samples = sum(v for k, v in counts.items() if k.endswith("/state"))
    probe: list[tuple[int, float]] = result["probe"]
    mb_seen: dict[int, float] = {}
    for regs, t in polled["changes"]:
        mb_seen.setdefault(_value_of(regs), t)
    z_seen: dict[int, float] = {}
    for _, v, t in z["records"]:
        z_seen.setdefault(round(v / POSITION_SCALE), t)
    sub_cpu = (z["cpu_s"] - sub0["cpu_s"]) / (z["at"] - sub0["at"])
    windows = result["windows"]
    quiet = [w for w in windows if w["t1"] <= poll_start]
    polled_windows = [w for w in windows if w["t0"] >= poll_start + 0.1 and w["t1"] <= poll_end]
    per_window: dict[str, list[float]] = {"mb_p50": [], "mb_p99": [], "z_p50": [], "z_p99": []}
    unseen = {"mb": 0, "z": 0}
    probed = 0
    for w in polled_windows:
        pw = [(v, t) for v, t in probe if w["t0"] <= t < w["t1"]]
        probed += len(pw)
        for kind, seen in (("mb", mb_seen), ("z", z_seen)):
            lat = _latencies_ms(pw, seen)
            unseen[kind] += len(pw) - len(lat)
            per_window[f"{kind}_p50"].append(percentile(lat, 50))
            per_window[f"{kind}_p99"].append(percentile(lat, 99))
    s = Summary.of
    sent = result["sent"]
    target_fps = N_NODES * 2 * 1000 / period_ms
    fps = result["load_sent"]["tpdo"] / result["wall_s"]
    decoded_fps = s([(result["frames_in"]) / (result["wall_s"] + result["drained_s"])])
    gw_cpu = s([w["gw_cpu"] * 100 for w in quiet])
    gw_cpu_polled = s([w["gw_cpu"] * 100 for w in polled_windows])
    rss_mib = s([w["rss_kib"] / 1024 for w in windows])
    peak_mib = result["rss"]["end"]["VmHWM"] / 1024
    backlog = s([w["backlog"] for w in windows])
    frames_lost = sent["tpdo"] + sent["emcy"] - result["tpdos_decoded"] - result["emcy_decoded"]
    values_lost = result["value_publications"] - value_samples
    events_lost = result["event_publications"] - emcy_samples - state_samples
    p = f"{label}: "
    rows = [
        Row(p + "TPDO frames/s generated", s([fps]), "target rate", s([target_fps]),
            s([fps / target_fps])),
        Row(p + "frames/s decoded, load + catch-up", decoded_fps),
        Row(p + "receive backlog (frames queued, per window)", backlog, target="stays near 0",
            met=backlog.maximum < 1000),
        Row(p + "gateway CPU, no Modbus client (% of one core, per window)", gw_cpu, digits=1),
        Row(p + "gateway CPU, a Modbus client polling in a tight loop (%)", gw_cpu_polled,
            digits=1),
        Row(p + "RSS (MiB, per window)", rss_mib, "before the gateway was built",
            s([result["rss"]["before_gateway"]["VmRSS"] / 1024]), target="<= 100 MiB",
            met=rss_mib.maximum <= 100, digits=1),
        Row(p + "peak RSS, VmHWM (MiB)", s([peak_mib]), target="<= 100 MiB", met=peak_mib <= 100,
            digits=1),
        Row(p + "TPDOs and EMCY not decoded after catch-up", s([frames_lost]), target="0",
            met=frames_lost == 0),
        Row(p + "value samples published but not received", s([values_lost]), target="0",
            met=values_lost == 0),
        Row(p + "events (EMCY, state) published but not received", s([events_lost]), target="0",
            met=events_lost == 0),
        Row(p + "nodes lost (heartbeat timeouts)", s([result["losses"]]), target="0",
            met=result["losses"] == 0),
        Row(p + "Modbus latency p50 (ms, per window)", s(per_window["mb_p50"]), digits=3),
        Row(p + "Modbus latency p99 (ms, per window)", s(per_window["mb_p99"]), target="<= 1 ms",
            met=s(per_window["mb_p99"]).median <= 1.0, digits=3),
        Row(p + "Zenoh latency p50 (ms, per window)", s(per_window["z_p50"]), digits=3),
        Row(p + "Zenoh latency p99 (ms, per window)", s(per_window["z_p99"]), target="<= 1 ms",
            met=s(per_window["z_p99"]).median <= 1.0, digits=3),
    ]  # fmt: skip
    threads = sorted(result["per_thread_cpu_s"].items(), key=lambda kv: -kv[1])
    notes = [
        p + f"of node 1's {probed:,} positions sent while the Modbus client polled, the client "
        f"never saw {unseen['mb']:,} (each value stands for one cycle; a value still queued when "
        f"the client stopped is never seen) and the Zenoh subscriber missed {unseen['z']:,}; "
        f"the subscriber process used {sub_cpu * 100:.0f}% of a core, the client polling in a "
        "tight loop about one core: both share the machine's two cores with the gateway.",
        p
        + "CPU by thread during the load (% of one core): "
        + ", ".join(
            f"{name} {cpu / result['wall_s'] * 100:.0f}" for name, cpu in threads if cpu > 0.01
        )
        + "; generator thread (excluded from the gateway figure) "
        + f"{s([w['gen_cpu'] * 100 for w in windows]).median:.0f}; the generator ran at most "
        + f"{result['generator_max_lag_s'] * 1000:.1f} ms behind its 1 ms slots.",
        p + f"sent {sent['tpdo']:,} TPDOs, {sent['heartbeat']:,} heartbeats, {sent['emcy']} EMCY; "
        f"the gateway decoded {result['frames_in']:,} frames and had emptied its receive queue "
        f"{result['drained_s']:.2f} s after the generator stopped"
        + (f" (still {result['backlog_left']:,} queued)" if result["backlog_left"] else "")
        + f"; Zenoh: {result['value_publications']:,} value publications, "
        f"{result['event_publications']:,} events; the subscriber got {value_samples:,} values, "
        f"{emcy_samples} EMCY, {state_samples} state events; nodes not alive at the end: "
        f"{result['not_alive']}. Gateway start with {N_NODES} nodes: {info['start_s']:.2f} s; "
        f"RSS {result['rss']['before_gateway']['VmRSS'] / 1024:.1f} MiB before the gateway "
        f"(interpreter and imports), {result['rss']['idle']['VmRSS'] / 1024:.1f} MiB started "
        "and idle.",
    ]
    return rows, notes


async def run(
    duration_s: float = 10.0,
    short_s: float = 5.0,
    window_s: float = 1.0,
    sim_s: float = 3.0,
) -> Section:
    half = 2 * PERIOD_MS
    sec = Section(
        key="scale",
        title=f"4. Scale: {N_NODES} nodes, {N_NODES * 2 * 1000 // PERIOD_MS:,} TPDO frames/s",
        method=(
            f"Gateway in its own process, {N_NODES} supervised SGH10 nodes (heartbeat "
            f"{HEARTBEAT_MS} ms), SYNC every TPDO period; a raw generator thread in that process "
            "sends TPDO1+TPDO2 of every node every period spread over 1 ms slots, the "
            f"heartbeats and one EMCY every {EMCY_EVERY_MS} ms. Scenarios: **default** "
            f"({PERIOD_MS} ms period, {N_NODES * 2000 // PERIOD_MS:,} frames/s, `publish: "
            "change`, the config default; the position moves every cycle and TPDO1 and TPDO2 "
            f"of a cycle carry the same values, as the SGH10 sends them) for {duration_s:g} s; "
            f"**worst case** (same rate, `publish: every`, every frame a new position: 2 "
            f"publications per frame) for {short_s:g} s; **half rate** (default settings, "
            f"{half} ms period, {N_NODES * 2000 // half:,} frames/s) for {short_s:g} s. CPU = "
            f"(process CPU - generator thread CPU) / wall per {window_s:g} s window, without a "
            f"Modbus client for the first {POLL_FROM:.0%} of a run, then with one polling in a "
            "tight loop; latency of node 1's positions to that client and to a Zenoh subscriber "
            "(processes of their own; the subscriber counts every sample the gateway publishes) "
            "per window while the client polls."
        ),
    )
    sim = Worker(SimRate, name="sim-rate")
    try:
        simrate = await sim.acall("measure", N_NODES, sim_s, timeout_s=120)
    finally:
        sim.close()
    for label, publish, distinct, period, dur in (
        ("default", "change", False, PERIOD_MS, duration_s),
        ("worst case", "every", True, PERIOD_MS, short_s),
        ("half rate", "change", False, half, short_s),
    ):
        rows, notes = await _scenario(label, publish, distinct, period, dur, window_s)
        sec.rows += rows
        sec.notes += notes
    target_fps = N_NODES * 2 * 1000 / PERIOD_MS
    sec.rows.append(
        Row("SimRunner with 127 SimNode: frames/s reached", Summary.of([simrate["fps"]]),
            "target rate", Summary.of([target_fps]), Summary.of([simrate["fps"] / target_fps]))
    )  # fmt: skip
    sec.notes.append(
        f"Simulator: SimRunner with {N_NODES} SimNode (TPDO1 on a {PERIOD_MS} ms event timer, "
        f"TPDO2 on SYNC every {PERIOD_MS} ms, heartbeat {HEARTBEAT_MS} ms) reached "
        f"{simrate['fps']:,.0f} frames/s using {simrate['cpu'] * 100:.0f}% of a core"
        + (f" (runner error: {simrate['error']})" if simrate["error"] else "")
        + " (the target is 127 x 2 TPDO / 10 ms + heartbeats = 26,670 frames/s; the count "
        "includes python-can's virtual bus copying each frame to the counting Bus)."
    )
    return sec
