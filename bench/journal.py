"""Benchmark 14, the store and forward journal (``journal.path``):

1. **Line rate, journal off against on**: the line-rate scenario (``bench.linerate``: 60 SGH10
   on a saturated 1 Mbit/s bus through socketcand, every value moving every frame, a PLC-like
   Modbus client, a Zenoh subscriber on every value, then a Modbus poller for latency), the
   gateway without a journal and with one (defaults: ``values_ms`` 1000), alternated in pairs
   (off, on, off, on...) so that drift of the machine hits both alike. CPU of the gateway
   process and p99 of frame -> Modbus and frame -> Zenoh side by side; the spread of the "off"
   runs is the run-to-run spread. With every value moving the publisher is behind and
   coalesces: how many samples it publishes (and so its CPU) follows the machine's load, so
   the CPU per value sample is given too.
2. **Events per second the journal sustains**: ``Journal.append`` of EMCY-sized entries (a
   payload as the gateway publishes, 170 bytes), each with a ``when_done`` callback, from one
   thread, as fast as it can: entries per second committed and called back, ``sync: normal``
   and ``full``.
3. **Backfill**: a gateway process (``canopen-gateway run``) whose journal holds 10,000 EMCY
   events of one key; a Zenoh client in this process asks ``<key>?_time=[..]`` and the time
   from the get to its last reply is measured (all 10,000 in seq order is checked).

Then ``bench/journal_loads.py``: 4. a 100k-row history answer beside a plain get, 5. the PLC
during a 100k-row export, 6. a stalled disk, 7. opening a full 256 MB journal (see there).

Imports: bench.*, canopen_gateway.journal (the store, for 2 and to fill 3), zenoh, tests.zenoh_client (the
session's config), the standard library; the gateway as a process (3) and in this process
(``journal_loads``).
"""

from __future__ import annotations

import asyncio
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

import yaml
import zenoh

from bench import journal_loads, linerate
from bench.report import Row, Section
from bench.rig import free_port
from bench.stats import Summary
from canopen_gateway.journal import Entry, Journal, ntp64_of_time
from tests.zenoh_client import session_config

REPO = pathlib.Path(__file__).resolve().parents[1]
PAIRS = 3
PHASE_S = 10.0
APPEND_N = 50_000
BACKFILL_N = 10_000
PREFIX = "canopen/jbench"
EMCY_PAYLOAD = json.dumps(
    {"node": "wire", "node_id": 1, "code": "0xFF05", "register": "0x81",
     "manufacturer": "0000000000", "text": "Position value error", "ts": 1.8e9,
     "count": 1, "seq": 1}
).encode()  # fmt: skip


async def line_rate() -> dict[str, list[dict[str, Any]]]:
    runs: dict[str, list[dict[str, Any]]] = {"off": [], "on": []}
    for i in range(PAIRS):
        for mode in ("off", "on") if i % 2 == 0 else ("on", "off"):  # neither always first
            journal = {} if mode == "on" else None
            r = await linerate._gateway_phase(PHASE_S, 0.0, {"every_value": True}, journal=journal)
            runs[mode].append(r)
    return runs


def thread_cpu(r: dict[str, Any], name: str) -> float:
    """% of one core of the gateway's threads of that name in a line-rate run."""
    return sum(c for n, _tid, c in r["threads"] if n.startswith(name)) * 100


def per_sample(r: dict[str, Any]) -> float:
    """Gateway CPU per value sample the subscriber received, microseconds: the publisher
    coalesces marks while it is behind, so total CPU follows how many samples it publishes."""
    return r["cpu"] / r["value_samples_per_s"] * 1e6 if r["value_samples_per_s"] else float("nan")


def value_call_us(n: int = 200_000) -> float:
    """The cost of ``Journal.value`` per call (a dict assignment under a lock), microseconds:
    what a pair's standby pays for each value sample it hears (``ZenohBridge.on_heard``, on a
    zenoh thread); the publishing gateway does not call it (``Journal.values_from``)."""
    j = Journal(pathlib.Path(tempfile.mkdtemp(prefix="bench-journal-")), values_ms=1000)
    e = Entry(1 << 62, "value", f"{PREFIX}/wire/value/position", "wire", 1, b"{}")
    keys = [f"{PREFIX}/n{i}/value/position" for i in range(120)]
    entries = [e._replace(key=k) for k in keys]
    t0 = time.perf_counter()
    for i in range(n):
        j.value(entries[i % 120])
    return (time.perf_counter() - t0) / n * 1e6


def sustained(sync: str, n: int = APPEND_N) -> float:
    """Entries per second appended, committed and called back."""
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-journal-"))
    j = Journal(tmp, values_ms=0, sync=sync)
    j.start()
    done = threading.Event()
    count = [0]

    def called() -> None:
        count[0] += 1
        if count[0] == n:
            done.set()

    t0 = time.perf_counter()
    for i in range(n):
        ticket = j.append(Entry(i + (1 << 62), "emcy", f"{PREFIX}/wire/emcy", "wire", i, EMCY_PAYLOAD))
        j.when_done(ticket, called)  # on the writer once committed
    done.wait(300)
    rate = n / (time.perf_counter() - t0)
    j.stop()
    return rate


def _fill(directory: pathlib.Path, n: int) -> None:
    j = Journal(directory, values_ms=0)
    j.start()
    now = time.time()
    for i in range(1, n + 1):
        body = json.loads(EMCY_PAYLOAD)
        body["seq"] = i
        j.append(Entry(ntp64_of_time(now - n + i * 0.5), "emcy", f"{PREFIX}/wire/emcy", "wire",
                       i, json.dumps(body).encode()))  # fmt: skip
    j.stop()


def backfill(n: int = BACKFILL_N) -> dict[str, float]:
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench-backfill-"))
    _fill(tmp / "journal", n)
    listen = f"tcp/127.0.0.1:{free_port()}"
    cfg = {
        "gateway": {"name": "jbench", "log_level": "warning"},
        "can": {"interface": "virtual", "channel": f"jbench{os.getpid()}"},
        "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
        "modbus": {"host": "127.0.0.1", "port": free_port()},
        "zenoh": {"listen": [listen], "prefix": PREFIX},
        "simulate": {"nodes": "all"},
        "journal": {"path": str(tmp / "journal")},
    }
    (tmp / "gw.yaml").write_text(yaml.safe_dump(cfg), encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "canopen_gateway", "run", "-c", str(tmp / "gw.yaml")],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    conf = session_config("peer", connect=[listen])
    session = None
    try:
        assert proc.stdout is not None
        proc.stdout.readline()  # the summary line: ready
        session = zenoh.open(conf)
        best = float("inf")
        seqs: list[int] = []
        for _ in range(3):
            t0 = time.perf_counter()
            seqs = []
            for r in session.get(f"{PREFIX}/wire/emcy?_time=[..]", timeout=120.0):
                if r.ok is not None:
                    seqs.append(json.loads(r.ok.payload.to_bytes())["seq"])
            best = min(best, time.perf_counter() - t0)
        return {
            "s": best,
            "replies": len(seqs),
            "in_order": float(seqs[:n] == list(range(1, n + 1))),
        }
    finally:
        if session is not None:
            session.close()
        proc.terminate()
        proc.wait(30)


async def run() -> Section:
    sec = Section(
        key="journal",
        title="14. Store and forward: the journal's cost at line rate, its rate, a backfill, under load and faults",
        method=__doc__.split("\n\n", 1)[1].split("Imports:")[0].strip(),
    )
    s = Summary.of
    runs = await line_rate()
    off, on = runs["off"], runs["on"]

    def col(rs: list[dict[str, Any]], k: str, scale: float = 1.0) -> list[float]:
        return [r[k] * scale for r in rs]

    cpu_off, cpu_on = col(off, "cpu", 100), col(on, "cpu", 100)
    ratios = [a / b for a, b in zip(cpu_on, cpu_off, strict=True) if b]
    ratio = s(ratios)
    sec.rows += [
        Row("gateway CPU, % of one core (journal on / off)", s(cpu_on), "off", s(cpu_off),
            ratio, "<= 1.05x (+5%)", ratio.median <= 1.05, digits=1),
        Row("frame -> Modbus p99 (ms), on / off", s(col(on, "mb_p99")), "off",
            s(col(off, "mb_p99")), digits=2),
        Row("frame -> Zenoh p99 (ms), on / off", s(col(on, "z_p99")), "off",
            s(col(off, "z_p99")), digits=2),
        Row("frames/s sent", s(col(on, "fps")), "off", s(col(off, "fps"))),
        Row("journal-writer thread CPU, % of one core (journal on)",
            s([thread_cpu(r, "journal-writer") for r in on]), digits=2),
        Row("zenoh-publish thread CPU, % of one core (it keeps SignalPub.last_pub), on / off",
            s([thread_cpu(r, "zenoh-publish") for r in on]), "off",
            s([thread_cpu(r, "zenoh-publish") for r in off]), digits=1),
        Row("value samples/s at the subscriber, on / off", s(col(on, "value_samples_per_s")),
            "off", s(col(off, "value_samples_per_s"))),
        Row("gateway CPU per value sample (us: CPU / samples received), on / off",
            s([per_sample(r) for r in on]), "off", s([per_sample(r) for r in off]), digits=1),
        Row("Journal.value per call (us; a standby's heard values)", s([value_call_us()]), digits=2),
    ]  # fmt: skip
    normal = await asyncio.to_thread(sustained, "normal")
    full = await asyncio.to_thread(sustained, "full", APPEND_N // 10)
    sec.rows += [
        Row("journal entries/s sustained, sync normal (EMCY-sized, callback each)", s([normal])),
        Row("journal entries/s sustained, sync full (an fsync per commit)", s([full])),
    ]
    b = await asyncio.to_thread(backfill)
    sec.rows += [
        Row(f"s to backfill {BACKFILL_N:,} events by one `_time` get (best of 3)", s([b["s"]]),
            digits=3),
        Row("... replies received, in seq order (1 = yes)", s([b["replies"]]), "in order",
            s([b["in_order"]])),
    ]  # fmt: skip
    await loads(sec)
    sec.notes.append(
        "Line rate runs alternate off/on "
        f"({PAIRS} pairs of {PHASE_S:g} s): CPU off {', '.join(f'{c:.1f}' for c in cpu_off)}, "
        f"on {', '.join(f'{c:.1f}' for c in cpu_on)} (% of one core)."
    )
    return sec


async def loads(sec: Section) -> None:
    """Rows 4 to 7 (``journal_loads``)."""
    s = Summary.of
    a = await journal_loads.answer_and_export()
    alone, beside, long = a["plain_alone"], a["plain_beside"], a["long"]
    idle, during = a["plc_idle"], a["plc_export"]
    rss0, rss1 = a["rss"]
    sec.rows += [
        Row(f"s to the last reply of a {journal_loads.ROWS:,}-row `_time` answer",
            s([long["s"]]), digits=2),
        Row("... its replies", s([long["replies"]]), target=f"{journal_loads.ROWS:,}",
            met=long["replies"] == journal_loads.ROWS),
        Row("plain `get <node>/state` beside it, max ms", s([beside["max"]]), "alone",
            s([alone["max"]]), target="<= 1000", met=beside["max"] <= 1000.0, digits=1),
        Row("... p50 ms", s([beside["p50"]]), "alone", s([alone["p50"]]), digits=2),
        Row(f"PLC answer p99 ms during a {journal_loads.ROWS:,}-row CSV export", s([during["p99"]]),
            "idle", s([idle["p99"]]), target="<= 10", met=during["p99"] <= 10.0, digits=2),
        Row("... max ms", s([during["max"]]), "idle", s([idle["max"]]), digits=2),
        Row("export s / MB", s([a["export"]["s"]]), "MB", s([a["export"]["bytes"] / 2**20]),
            digits=2),
        Row("gateway RSS MiB after the export", s([rss1]), "before", s([rss0]),
            target="+ <= 8 MiB", met=rss1 - rss0 <= 8.0, digits=1),
    ]  # fmt: skip
    if long["err"]:
        sec.notes.append(f"the long answer ended with: {long['err']}")
    stall = await journal_loads.stalled_disk()
    if isinstance(stall, str):
        sec.notes.append(f"stalled disk not measured: {stall}")
    else:
        fr, ok = stall["frozen"], stall["answering"]
        sec.rows += [
            Row("EMCY frame -> subscriber ms, p50, journal's filesystem frozen", s([fr["p50"]]),
                "answering", s([ok["p50"]]), target="200 (the bound) + the path",
                met=fr["p50"] <= 200.0 + 2 * ok["p50"] + 10.0, digits=1),
            Row("... max ms", s([fr["max"]]), "answering", s([ok["max"]]), digits=1),
        ]  # fmt: skip
        st = stall["status"]
        sec.notes.append(
            f"while frozen /healthz journal said: journaling {st.get('journaling')}, "
            f"published_unjournaled {st.get('published_unjournaled')}, error `{st.get('error')}`."
        )
    op = await asyncio.to_thread(journal_loads.full_open)
    sec.rows.append(
        Row(f"ms to open a full journal ({op['mb']:.0f} MB, {op['rows']:,.0f} rows)", s([op["full"]]),
            "empty", s([op["empty"]]), target="<< 1000", met=op["full"] < 100.0, digits=1)
    )  # fmt: skip


def main() -> None:
    from bench.report import render_section

    print("\n".join(render_section(asyncio.run(run()))))


if __name__ == "__main__":
    main()
