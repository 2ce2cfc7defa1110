"""The journal under load and under faults (benchmark 14, continued; ``bench/journal.py`` runs
it in its section):

4. **A 100k-row history answer beside a plain get**: the gateway (in the bench process, the
   SGH10 simulated, its journal filled with 100,000 EMCY events of one key before it starts);
   a Zenoh client in its own process asks ``<key>?_time=[..]`` (every row) and, while the
   answer streams, a plain ``get <prefix>/wire/state`` every 100 ms: the plain gets' latency
   (p50, max) against the same gets with no history answer running, and the time to the long
   answer's last reply (or its ``cut`` at Zenoh's get timeout).
5. **The PLC during an export**: the same gateway; a PLC in its own process reads 3 input
   registers every 10 ms (``bench.plc_first.PlcPoller``); a client in another process
   downloads ``/api/journal.csv`` of the 100,000 rows (chunked): the PLC's p99 and maximum
   during the export against idle, the export's time and size, the gateway's RSS before and
   after.
6. **A stalled disk**: the journal on a loop-mounted ext4 image (root only; skipped otherwise),
   EMCY frames sent one at a time, the time from the frame to the sample at a subscriber in
   its own process: while the disk answers, and while its filesystem is frozen (``fsfreeze``):
   an event waits for its commit 200 ms at most, then is published.
7. **Opening a full journal**: a 256 MB journal (about 800,000 EMCY-sized rows, written
   directly with SQLite), opened by ``Journal.open`` (the lock, the damage check, the marks):
   the time against an empty journal's (no full scan: milliseconds).

Imports: bench.*, canopen_gateway.config, canopen_gateway.journal, zenoh (in the client processes), the standard
library.
"""

from __future__ import annotations

import asyncio
import json
import os
import pathlib
import shutil
import statistics
import subprocess
import tempfile
import threading
import time
import urllib.request
from typing import Any

import can

from bench.plc_first import PlcPoller
from bench.rig import free_port, gateway_of, unique_channel, wait_until
from bench.stats import percentile
from bench.workers import Worker
from canopen_gateway.config import parse_config
from canopen_gateway.journal import Entry, Journal, ntp64_of_time

PREFIX = "canopen/jload"
KEY = f"{PREFIX}/wire/emcy"
ROWS = 100_000
PLAIN_EVERY_S = 0.1
EMCY_WIRE = 0x81  # CiA 301: EMCY of node 1
PAYLOAD = json.dumps({"node": "wire", "node_id": 1, "code": "0xFF05", "register": 129,
                      "manufacturer": "0000000000", "text": "Position value error",
                      "reset": False, "current_errors": ["0xFF05"], "ts": 1.8e9, "count": 1,
                      "seq": 1}).encode()  # fmt: skip


# ---------------------------------------------------------------------- client processes
class HistoryProbe:
    """A Zenoh peer: plain gets timed alone, and beside one long history answer."""

    def __init__(self, endpoint: str) -> None:
        import zenoh

        from tests.zenoh_client import session_config

        self.zenoh = zenoh
        self.session = zenoh.open(session_config("peer", connect=[endpoint]))

    def _plain(self, key: str, until: threading.Event, limit_s: float) -> list[float]:
        out = []
        t_end = time.perf_counter() + limit_s
        while not until.is_set() and time.perf_counter() < t_end:
            t0 = time.perf_counter()
            replies = list(self.session.get(key, timeout=10.0))
            ok = any(r.ok is not None for r in replies)
            out.append(time.perf_counter() - t0 if ok else float("inf"))
            time.sleep(PLAIN_EVERY_S)
        return out

    def alone(self, key: str, seconds: float) -> list[float]:
        return self._plain(key, threading.Event(), seconds)

    def beside(self, long_selector: str, key: str) -> dict[str, Any]:
        done = threading.Event()
        got = {"ok": 0, "err": ""}
        t0 = time.perf_counter()

        def on_reply(reply: Any) -> None:
            if reply.ok is not None:
                got["ok"] += 1
            else:
                got["err"] = reply.err.payload.to_string()[:200]

        def on_end() -> None:
            got["s"] = time.perf_counter() - t0
            done.set()

        handler = self.zenoh.handlers.Callback(on_reply, on_end)
        self.session.get(long_selector, handler, timeout=60.0)
        plain = self._plain(key, done, 60.0)
        done.wait(60.0)
        return {"plain": plain, **got}

    def close(self) -> None:
        self.session.close()


class ExportClient:
    """Downloads a URL (the console's chunked export) and says how long and how much."""

    info = None

    def download(self, url: str) -> dict[str, float]:
        t0 = time.perf_counter()
        n = 0
        with urllib.request.urlopen(url, timeout=120.0) as r:
            while chunk := r.read(65536):
                n += len(chunk)
        return {"s": time.perf_counter() - t0, "bytes": float(n)}


class EventProbe:
    """A Zenoh peer subscribed to the EMCY key: the arrival time (perf_counter) of each seq."""

    def __init__(self, endpoint: str, key: str) -> None:
        import zenoh

        from tests.zenoh_client import session_config

        self.session = zenoh.open(session_config("peer", connect=[endpoint]))
        self.arrived: dict[int, float] = {}
        self.sub = self.session.declare_subscriber(key, self._on)

    def _on(self, sample: Any) -> None:
        self.arrived[json.loads(sample.payload.to_bytes())["seq"]] = time.perf_counter()

    def arrivals(self) -> dict[int, float]:
        return dict(self.arrived)

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


# ---------------------------------------------------------------------- the rig
def fill(directory: pathlib.Path, n: int, span_s: float = 3000.0) -> None:
    """``n`` EMCY entries of ``KEY`` within the last ``span_s`` seconds, through the journal."""
    j = Journal(directory, values_ms=0)
    j.start()
    now = time.time()
    ticket = 0
    for i in range(1, n + 1):
        body = json.loads(PAYLOAD)
        body["seq"] = i
        e = Entry(ntp64_of_time(now - span_s + i * span_s / n), "emcy", KEY, "wire", i,
                  json.dumps(body).encode())  # fmt: skip
        ticket = j.append(e) or ticket
        if i % 20_000 == 0:
            j.wait(ticket, 60)
    j.wait(ticket, 60)
    j.stop()


def config(journal: str, **extra: Any) -> Any:
    return parse_config(
        {
            "gateway": {"name": "jload", "log_level": "error"},
            "can": {"interface": "virtual", "channel": unique_channel("jload")},
            "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
            "modbus": {"host": "127.0.0.1", "port": free_port()},
            "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"], "prefix": PREFIX},
            "health": {"host": "127.0.0.1", "port": free_port()},
            "simulate": {"nodes": "all"},
            "journal": {"path": journal},
            **extra,
        },
        environ={},
    )


def _ms(values: list[float]) -> dict[str, float]:
    ms = [v * 1000.0 for v in values]
    return {
        "p50": statistics.median(ms) if ms else float("nan"),
        "p99": percentile(ms, 99) if ms else float("nan"),
        "max": max(ms, default=float("nan")),
        "n": float(len(ms)),
    }


def _rss_mib() -> float:
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


async def answer_and_export() -> dict[str, Any]:
    """Measurements 4 and 5 on one gateway (see the module docstring)."""
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-jload-"))
    await asyncio.to_thread(fill, tmp / "journal", ROWS)
    cfg = config(str(tmp / "journal"))
    gw = gateway_of(cfg, freeze_gc=True)
    await gw.start()
    probe = plc = export = None
    out: dict[str, Any] = {}
    try:
        await wait_until(lambda: gw.image.nodes["wire"].usable(), 30, "wire usable")
        probe = Worker(HistoryProbe, cfg.zenoh.listen[0], name="history-probe")
        state = f"{PREFIX}/wire/state"
        out["plain_alone"] = _ms(await probe.acall("alone", state, 3.0, timeout_s=60))
        beside = await probe.acall("beside", f"{KEY}?_time=[..]", state, timeout_s=180)
        out["plain_beside"] = _ms(beside["plain"])
        out["long"] = {"s": beside.get("s", float("nan")), "replies": beside["ok"], "err": beside["err"]}

        plc = Worker(PlcPoller, name="plc")
        export = Worker(ExportClient, name="export")
        port = cfg.modbus.port
        await plc.acall("start", "127.0.0.1", port, 1, 0, 3, 0.010)
        await asyncio.sleep(3.0)
        out["plc_idle"] = _ms((await plc.acall("stop"))["rtts"])
        rss0 = _rss_mib()
        url = f"http://127.0.0.1:{cfg.health.port}/api/journal.csv?kind=emcy&from=now(-2h)"
        await plc.acall("start", "127.0.0.1", port, 1, 0, 3, 0.010)
        out["export"] = await export.acall("download", url, timeout_s=300)
        out["plc_export"] = _ms((await plc.acall("stop"))["rtts"])
        out["rss"] = (rss0, _rss_mib())
    finally:
        for w in (probe, plc, export):
            if w is not None:
                w.close()
        await gw.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    return out


async def stalled_disk() -> dict[str, Any] | str:
    """Measurement 6; a text saying why it was not made when it cannot be."""
    if os.geteuid() != 0 or not all(shutil.which(t) for t in ("mkfs.ext4", "mount", "fsfreeze")):
        return "needs root, mkfs.ext4, mount and fsfreeze"
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-jstall-"))
    image, mnt = tmp / "disk.img", tmp / "disk"
    mnt.mkdir()
    with open(image, "wb") as f:
        f.truncate(64 << 20)
    subprocess.run(["mkfs.ext4", "-q", str(image)], check=True)
    if subprocess.run(["mount", "-o", "loop", str(image), str(mnt)], capture_output=True).returncode:
        shutil.rmtree(tmp, ignore_errors=True)
        return "a loop mount is not possible here"
    cfg = config(str(mnt / "journal"))
    gw = gateway_of(cfg)
    probe = None
    frozen = False
    out: dict[str, Any] = {}
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    try:
        await gw.start()
        await wait_until(lambda: gw.image.nodes["wire"].usable(), 30, "wire usable")
        probe = Worker(EventProbe, cfg.zenoh.listen[0], KEY, name="event-probe")
        seq = [0]

        async def events(n: int) -> list[float]:
            sent: dict[int, float] = {}
            for _ in range(n):
                seq[0] += 1
                sent[seq[0]] = time.perf_counter()
                data = (0xFF05 if seq[0] % 2 else 0).to_bytes(2, "little") + bytes(6)
                bus.send(can.Message(arbitration_id=EMCY_WIRE, data=data, is_extended_id=False))
                await asyncio.sleep(0.05)
            await asyncio.sleep(1.0)
            got = await probe.acall("arrivals")
            return [got[s] - t if s in got else float("inf") for s, t in sent.items()]

        await events(5)  # matched
        seq[0] = len(await probe.acall("arrivals"))
        out["answering"] = _ms(await events(40))
        subprocess.run(["fsfreeze", "-f", str(mnt)], check=True)
        frozen = True
        out["frozen"] = _ms(await events(40))
        out["status"] = gw.journal.status() if gw.journal is not None else {}
        subprocess.run(["fsfreeze", "-u", str(mnt)], check=True)
        frozen = False
    finally:
        if frozen:
            subprocess.run(["fsfreeze", "-u", str(mnt)], capture_output=True)
        if probe is not None:
            probe.close()
        bus.shutdown()
        await gw.stop()
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def full_open(megabytes: int = 256) -> dict[str, float]:
    """Measurement 7: ``Journal.open`` of a full journal and of an empty one, milliseconds."""
    import sqlite3

    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-jopen-"))
    try:
        j = Journal(tmp / "full", values_ms=0)
        j.open()
        j.stop()
        con = sqlite3.connect(tmp / "full" / "journal.sqlite3")
        now = time.time()
        i = 0
        while (tmp / "full" / "journal.sqlite3").stat().st_size < megabytes << 20:
            rows = [(ntp64_of_time(now - 1e6 + (i + k) * 0.001) - (1 << 63), "emcy", KEY, "wire",
                     i + k, PAYLOAD, None) for k in range(50_000)]  # fmt: skip
            con.executemany("INSERT INTO entries(t, kind, key, node, seq, payload, tid) "
                            "VALUES (?, ?, ?, ?, ?, ?, ?)", rows)  # fmt: skip
            con.commit()
            i += 50_000
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        con.close()
        out = {"rows": float(i), "mb": (tmp / "full" / "journal.sqlite3").stat().st_size / 2**20}
        for name in ("full", "empty"):
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                j = Journal(tmp / name, values_ms=0)
                j.open()
                times.append((time.perf_counter() - t0) * 1000.0)
                j.stop()
            out[name] = min(times)
        return out
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
