"""Benchmark 13, the PLC first: a PLC's Modbus answers while Zenoh and console clients burst.

Rig: the demo's five devices simulated in the bench process beside the gateway (prefix
``canopen/bench``, Modbus, Zenoh and the console on free loopback ports). A PLC in its own
process (a plain socket, no Modbus library in the way) reads 3 input registers of unit 1 every
10 ms and records the time of each answer. Another process is the load: a Zenoh peer connected
to the gateway fires bursts of concurrent ``get`` (each burst waits until every get has ended:
answered, refused or timed out) or a steady rate of them, or HTTP clients ask the console's
API concurrently; the gateway keeps a journal (in a temporary directory), and the last load is
bursts of history gets (``_time``) answered from it. Per load, the PLC's answers during the load (from its first request to the
end of its last burst) give p99 and maximum, beside the idle figure of the same run; the
gateway's resident memory (VmRSS of the bench process, which is the gateway's) is read before
the first load and after the last.

``python -m bench plc-first`` (or ``python -m bench.plc_first``) prints the section.

Imports: bench.*, canopen_gateway.config, the standard library (zenoh and tests.zenoh_client in the load
process only).
"""

from __future__ import annotations

import asyncio
import gc
import logging
import os
import socket
import struct
import tempfile
import threading
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from bench.report import Row, Section, render_section
from bench.rig import free_port, gateway_of, unique_channel, wait_until
from bench.stats import Summary, percentile
from bench.workers import Worker
from canopen_gateway.config import parse_config

PREFIX = "canopen/bench"
PLC_PERIOD_S = 0.010
IDLE_S = 3.0
GET_TIMEOUT_S = 10.0
STEADY_S = 5.0
TARGET_P99_MS = 10.0
TARGET_MAX_MS = 50.0
#: ``PLC_FIRST_FREEZE_GC=0``: the gateway without ``gc.freeze`` after its start
FREEZE_GC = os.environ.get("PLC_FIRST_FREEZE_GC", "1") != "0"
#: (name, kind, argument, count per burst, bursts or rate)
LOADS: list[tuple[str, str, str, int, float]] = [
    (f"4 bursts of 500 concurrent `get {PREFIX}/**`", "burst", f"{PREFIX}/**", 500, 4),
    (f"10 bursts of 500 concurrent `get {PREFIX}/wire/snapshot`", "burst",
     f"{PREFIX}/wire/snapshot", 500, 10),
    (f"a steady 200 `get {PREFIX}/**` per second for {STEADY_S:.0f} s", "steady", f"{PREFIX}/**",
     0, 200),
    ("4 bursts of 200 concurrent console `GET /api/overview`", "http", "/api/overview", 200, 4),
    ("4 bursts of 200 concurrent console `GET /api/node/wire`", "http", "/api/node/wire", 200, 4),
    # last: the journal has collected the values of every load before (one sample per signal
    # and second), so each answer is hundreds of samples read from SQLite
    (f"4 bursts of 100 concurrent history gets `{PREFIX}/**?_time=[now(-1h)..]`", "burst",
     f"{PREFIX}/**?_time=[now(-1h)..]", 100, 4),
]  # fmt: skip
_MBAP_READ = struct.Struct(">HHHBBHH")


# ---------------------------------------------------------------------- the PLC (own process)
class PlcPoller:
    """Reads ``count`` input registers every ``period_s`` over one TCP connection (a thread of
    its own); ``start`` / ``stop`` bound a window and ``stop`` returns its answer times."""

    info = None

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._rtts: list[float] = []
        self._errors = 0

    def start(
        self, host: str, port: int, unit: int, address: int, count: int, period_s: float
    ) -> bool:
        self._stop.clear()
        self._rtts, self._errors = [], 0
        args = (host, port, unit, address, count, period_s)
        self._thread = threading.Thread(target=self._run, args=args, daemon=True)
        self._thread.start()
        return True

    def _run(
        self, host: str, port: int, unit: int, address: int, count: int, period_s: float
    ) -> None:
        clock = time.perf_counter
        with socket.create_connection((host, port), timeout=60.0) as s:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            want = 9 + 2 * count
            tid = 0
            nxt = clock()
            while not self._stop.is_set():
                tid = (tid + 1) & 0xFFFF
                t0 = clock()
                s.sendall(_MBAP_READ.pack(tid, 0, 6, unit, 4, address, count))
                got = b""
                while len(got) < 9 or len(got) < 6 + int.from_bytes(got[4:6], "big"):
                    chunk = s.recv(256)
                    if not chunk:
                        raise ConnectionError("the gateway closed the PLC's connection")
                    got += chunk
                self._rtts.append(clock() - t0)
                if len(got) != want or got[7] != 4:
                    self._errors += 1
                nxt += period_s
                delay = nxt - clock()
                if delay > 0:
                    time.sleep(delay)
                else:
                    nxt = clock()  # late: the next request goes now, no catch-up burst

    def stop(self) -> dict[str, Any]:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10.0)
        return {"rtts": self._rtts, "errors": self._errors}


# ---------------------------------------------------------------------- the load (own process)
class QueryLoad:
    """A Zenoh peer connected to the gateway, and an HTTP client pool for the console."""

    def __init__(self, endpoint: str) -> None:
        import zenoh

        from tests.zenoh_client import session_config

        self.zenoh = zenoh
        self.session = zenoh.open(session_config("peer", connect=[endpoint]))
        self.info = {"zid": str(self.session.info.zid())}
        self.errors: dict[str, str] = {}  # the first error text of each kind

    def first_errors(self) -> dict[str, str]:
        out, self.errors = self.errors, {}
        return out

    def _fire(
        self, selector: str, n: int, tally: dict[str, int], done: threading.Semaphore
    ) -> None:
        lock = threading.Lock()
        errors = self.errors

        def on_reply(reply: Any) -> None:
            with lock:
                if reply.ok is not None:
                    tally["ok"] += 1
                else:
                    err = reply.err.payload.to_bytes()
                    kind = "busy" if b'"busy"' in err else "err"
                    tally[kind] += 1
                    errors.setdefault(kind, err.decode(errors="replace")[:160])

        for _ in range(n):
            handler = self.zenoh.handlers.Callback(on_reply, done.release)
            self.session.get(selector, handler, timeout=GET_TIMEOUT_S)

    def burst(self, selector: str, n: int, bursts: int) -> dict[str, Any]:
        """``bursts`` times: ``n`` concurrent gets, then wait until all of them ended."""
        tally = {"ok": 0, "err": 0, "busy": 0}
        ended = 0
        for _ in range(bursts):
            done = threading.Semaphore(0)
            self._fire(selector, n, tally, done)
            for _ in range(n):
                if done.acquire(timeout=GET_TIMEOUT_S * 3):
                    ended += 1
        return {**tally, "gets": n * bursts, "ended": ended}

    def steady(self, selector: str, rate: float, duration_s: float) -> dict[str, Any]:
        tally = {"ok": 0, "err": 0, "busy": 0}
        done = threading.Semaphore(0)
        n = int(rate * duration_s)
        t0 = time.perf_counter()
        for i in range(n):
            delay = t0 + i / rate - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            self._fire(selector, 1, tally, done)
        ended = sum(1 for _ in range(n) if done.acquire(timeout=GET_TIMEOUT_S * 3))
        return {**tally, "gets": n, "ended": ended}

    def http(self, url: str, n: int, bursts: int) -> dict[str, Any]:
        tally = {"ok": 0, "err": 0, "busy": 0, "gets": n * bursts, "ended": 0}

        def one(_: int) -> int:
            try:
                with urllib.request.urlopen(url, timeout=GET_TIMEOUT_S) as r:
                    r.read()
                    return int(r.status)
            except urllib.error.HTTPError as exc:
                return int(exc.code)
            except OSError:
                return 0

        with ThreadPoolExecutor(max_workers=n) as pool:
            for _ in range(bursts):
                for status in pool.map(one, range(n)):
                    tally["ended"] += 1
                    key = "ok" if status == 200 else "busy" if status in (429, 503) else "err"
                    tally[key] += 1
        return tally

    def close(self) -> None:
        self.session.close()


# ---------------------------------------------------------------------- the rig
def _rss_mib() -> float:
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _config(endpoint: str, modbus_port: int, http_port: int, journal: str) -> Any:
    return parse_config(
        {
            "gateway": {"name": "bench", "log_level": "warning"},
            "can": {"interface": "virtual", "channel": unique_channel("plc-first")},
            "master": {"node_id": 127, "heartbeat_ms": 500, "sync_period_ms": 100},
            "nodes": [
                {"name": "wire", "node_id": 1, "profile": "sgh10"},
                {"name": "magnet", "node_id": 2, "profile": "msk5000",
                 "sdo": [{"object": "0x5115:00", "value": 1}]},
                {"name": "rotary", "node_id": 3, "profile": "posi_plus"},
                {"name": "rotary_sf", "node_id": 4, "profile": "posi_sf"},
                {"name": "display", "node_id": 125, "profile": "ap05"},
            ],
            "modbus": {"host": "127.0.0.1", "port": modbus_port},
            "zenoh": {"mode": "peer", "listen": [endpoint]},
            "health": {"host": "127.0.0.1", "port": http_port},
            "simulate": {"nodes": "all"},
            "journal": {"path": journal},
        },
        environ={},
    )  # fmt: skip


def _figures(rtts: list[float]) -> dict[str, float]:
    ms = [x * 1000.0 for x in rtts]
    return {"p99": percentile(ms, 99), "max": max(ms, default=float("nan")), "n": len(ms)}


async def _measure(plc: Worker, load: Worker, port: int, what: tuple[str, str, str, int, float],
                   http_base: str) -> tuple[dict[str, float], dict[str, Any]]:  # fmt: skip
    _name, kind, arg, n, x = what
    await plc.acall("start", "127.0.0.1", port, 1, 0, 3, PLC_PERIOD_S)
    if kind == "burst":
        res = await load.acall("burst", arg, n, int(x), timeout_s=600)
    elif kind == "steady":
        res = await load.acall("steady", arg, x, STEADY_S, timeout_s=600)
    elif kind == "http":
        res = await load.acall("http", http_base + arg, n, int(x), timeout_s=600)
    else:
        await asyncio.sleep(IDLE_S)
        res = {}
    got = await plc.acall("stop")
    return {**_figures(got["rtts"]), "errors": got["errors"]}, res


async def run() -> Section:
    logging.getLogger("gateway").setLevel(logging.ERROR)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    journal_dir = tempfile.TemporaryDirectory(prefix="bench-plc-first-")
    cfg = _config(endpoint, free_port(), free_port(), journal_dir.name)
    gw = gateway_of(cfg, freeze_gc=FREEZE_GC)  # as ``canopen-gateway run`` does
    await gw.start()
    pauses: list[float] = []
    gc_t0 = [0.0]

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if info.get("generation") != 2:
            return
        if phase == "start":
            gc_t0[0] = time.perf_counter()
        else:
            pauses.append(time.perf_counter() - gc_t0[0])

    gc.callbacks.append(on_gc)
    plc = load = None
    rows: list[Row] = []
    notes: list[str] = []
    try:
        await wait_until(lambda: all(n.usable() for n in gw.image.nodes.values()), 30, "nodes")
        plc = Worker(PlcPoller, name="plc")
        load = Worker(QueryLoad, endpoint, name="query-load")
        http_base = f"http://127.0.0.1:{cfg.health.port}"
        await _measure(
            plc, load, cfg.modbus.port, ("warm", "burst", f"{PREFIX}/**", 20, 1), http_base
        )
        rss0 = _rss_mib()
        idle, _ = await _measure(plc, load, cfg.modbus.port, ("idle", "idle", "", 0, 0), http_base)
        rows.append(_row("idle", idle))
        only = os.environ.get("PLC_FIRST_LOADS", "")  # e.g. "http" or "burst,steady"
        for what in LOADS:
            if only and what[1] not in only.split(","):
                continue
            fig, res = await _measure(plc, load, cfg.modbus.port, what, http_base)
            first = await load.acall("first_errors")
            rows.append(_row(what[0], fig))
            notes.append(
                f"{what[0]}: {res.get('gets', 0)} requests, {res.get('ok', 0)} answers, "
                f"{res.get('busy', 0)} refused busy, {res.get('err', 0)} other errors, "
                f"{res.get('ended', 0)} ended; the PLC got {int(fig['n'])} answers "
                f"({int(fig['errors'])} not a register answer)."
                + "".join(f" First {k}: `{v}`." for k, v in sorted(first.items()))
            )
        rss1 = _rss_mib()
        notes.append(
            f"full garbage collections during the loads: {len(pauses)}, the longest "
            f"{max(pauses, default=0.0) * 1000:.1f} ms (a stall of every thread)."
        )
        rows.append(Row("gateway RSS before the loads, MiB", Summary.of([rss0]), digits=1))
        rows.append(Row("gateway RSS after the loads, MiB", Summary.of([rss1]), digits=1,
                        target="+ <= 2 MiB", met=rss1 - rss0 <= 2.0))  # fmt: skip
    finally:
        gc.callbacks.remove(on_gc)
        for w in (plc, load):
            if w is not None:
                w.close()
        await gw.stop()
        journal_dir.cleanup()
    return Section(
        key="plc-first",
        title="13. The PLC first: Modbus answers during bursts of queries",
        method=__doc__.split("\n\n")[1].replace("\n", " ") if __doc__ else "",
        rows=rows,
        notes=notes,
    )


def _row(name: str, fig: dict[str, float]) -> Row:
    return Row(
        f"PLC answer ms, p99 / max: {name} ({int(fig['n'])} answers; max {fig['max']:.1f} ms)",
        Summary.of([fig["p99"]]),
        digits=2,
        target=f"p99 <= {TARGET_P99_MS:.0f}, max <= {TARGET_MAX_MS:.0f}",
        met=fig["p99"] <= TARGET_P99_MS and fig["max"] <= TARGET_MAX_MS,
    )


def main() -> None:
    logging.basicConfig(level=logging.ERROR)
    sec = asyncio.run(run())
    print("\n".join(render_section(sec)))


if __name__ == "__main__":
    main()
