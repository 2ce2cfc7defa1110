"""Benchmark 3, Modbus throughput: 10-register reads per second against a bare pymodbus server.

The gateway serves a node's input registers 0..9 (node diagnostics: quality, NMT state, alive,
lifecycle, data age, EMCY code / register / count, losses), computed from the process image on
every request. The baseline is a pymodbus ``ModbusTcpServer`` with a ``SimDevice`` holding as
many registers as the node's unit spans (0..102), read at the same addresses. Clients: 1 and 4
synchronous pymodbus clients, each in its own process, and, when ``/usr/include/modbus/modbus.h``
exists (Debian ``libmodbus-dev``), 1 and 4 processes of a small libmodbus C client compiled here
at run time. Windows of gateway and bare server alternate, repetition by repetition.

Imports: bench.*, gateway (through bench.rig), pymodbus.
"""

from __future__ import annotations

import asyncio
import os
import pathlib
import shutil
import subprocess
import tempfile
import time

from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from bench.report import Row, Section
from bench.rig import Injector, bench_config, bench_node, free_port, start_gateway
from bench.stats import Summary, paired_ratios
from bench.workers import Worker, start_load

ADDRESS, COUNT = 0, 10
MODBUS_H = pathlib.Path("/usr/include/modbus/modbus.h")

C_CLIENT = r"""
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <modbus/modbus.h>

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* mbclient host port unit address count duration_s start_at (CLOCK_MONOTONIC seconds) */
int main(int argc, char **argv) {
    if (argc != 8) return 64;
    int count = atoi(argv[5]);
    double duration = atof(argv[6]), start_at = atof(argv[7]);
    uint16_t regs[125];
    modbus_t *ctx = modbus_new_tcp(argv[1], atoi(argv[2]));
    modbus_set_slave(ctx, atoi(argv[3]));
    if (modbus_connect(ctx) == -1) {
        fprintf(stderr, "connect: %s\n", modbus_strerror(errno));
        return 1;
    }
    if (modbus_read_input_registers(ctx, atoi(argv[4]), count, regs) != count) {
        fprintf(stderr, "read: %s\n", modbus_strerror(errno));
        return 2;
    }
    while (now() < start_at) {
        struct timespec d = {0, 200000};
        nanosleep(&d, NULL);
    }
    long n = 0, errors = 0;
    double t0 = now(), end = t0 + duration;
    while (now() < end) {
        if (modbus_read_input_registers(ctx, atoi(argv[4]), count, regs) != count) errors++;
        n++;
    }
    printf("%ld %ld %.6f\n", n, errors, now() - t0);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}
"""


def build_c_client(workdir: pathlib.Path) -> tuple[pathlib.Path | None, str]:
    """Compile the libmodbus client; (path, "") or (None, why not)."""
    gcc = shutil.which("gcc")
    if not MODBUS_H.exists():
        return None, f"{MODBUS_H} missing (apt-get install -y libmodbus-dev)"
    if gcc is None:
        return None, "no gcc"
    src = workdir / "mbclient.c"
    exe = workdir / "mbclient"
    src.write_text(C_CLIENT, encoding="ascii")
    out = subprocess.run(
        [gcc, "-O2", "-o", str(exe), str(src), "-lmodbus"],
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        return None, f"gcc failed: {out.stderr.strip()[:300]}"
    return exe, ""


async def _c_window(exe: pathlib.Path, port: int, unit: int, n: int, duration_s: float) -> float:
    start_at = time.perf_counter() + 0.15
    args = [str(exe), "127.0.0.1", str(port), str(unit), str(ADDRESS), str(COUNT), str(duration_s), f"{start_at:.6f}"]  # fmt: skip
    procs = [
        await asyncio.create_subprocess_exec(
            *args, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE
        )
        for _ in range(n)
    ]
    rate = 0.0
    for p in procs:
        out, err = await p.communicate()
        if p.returncode != 0:
            raise RuntimeError(f"mbclient exit {p.returncode}: {err.decode().strip()}")
        requests, errors, elapsed = out.split()
        if int(errors):
            raise RuntimeError(f"mbclient: {int(errors)} failed reads on port {port}")
        rate += int(requests) / float(elapsed)
    return rate


async def _py_window(workers: list[Worker], port: int, unit: int, duration_s: float) -> float:
    start_at = time.perf_counter() + 0.1
    results = await asyncio.gather(
        *(
            w.acall("run", "127.0.0.1", port, unit, ADDRESS, COUNT, start_at, duration_s)
            for w in workers
        )
    )
    for r in results:
        if r["errors"]:
            raise RuntimeError(f"{r['errors']} failed reads on port {port}")
    return sum(r["requests"] / r["elapsed_s"] for r in results)


async def run(reps: int = 5, window_s: float = 0.8) -> Section:
    sec = Section(
        key="modbus",
        title="3. Modbus throughput: 10-register reads per second",
        method=(
            f"Read of {COUNT} input registers ({ADDRESS}..{ADDRESS + COUNT - 1} of the node's "
            f"unit: diagnostics computed from the process image) in a loop, {reps} windows of "
            f"{window_s:g} s per client setup, gateway and bare server alternating. Baseline: "
            "pymodbus ModbusTcpServer with a SimDevice of 103 registers, same addresses. Each "
            "client is a process of its own (synchronous pymodbus ModbusTcpClient, or the "
            "libmodbus C client); the figure is the sum of the clients' requests/s."
        ),
    )
    cfg = bench_config([bench_node("n1", 1)], "modbus")
    inj = Injector(cfg.can.channel)
    gw = await start_gateway(cfg, inj, [1])
    assert gw.modbus is not None
    bare_port = free_port()
    dev = SimDevice(id=1, simdata=[SimData(0, count=103, datatype=DataType.REGISTERS)])
    bare = ModbusTcpServer(dev, address=("127.0.0.1", bare_port))
    await bare.serve_forever(background=True)
    workers = await asyncio.to_thread(start_load, 4)
    tmp = tempfile.TemporaryDirectory(prefix="bench-mbclient-")
    exe, why = build_c_client(pathlib.Path(tmp.name))
    setups: list[tuple[str, int]] = [("pymodbus", 1), ("pymodbus", 4)]
    if exe is not None:
        setups += [("libmodbus", 1), ("libmodbus", 4)]
    else:
        sec.notes.append(f"libmodbus C client skipped: {why}.")
    res: dict[tuple[str, int, str], list[float]] = {}
    cpu: dict[tuple[str, int, str], list[float]] = {}
    try:
        for client, n in setups:
            for _rep in range(reps):
                for server, port in (("gw", gw.modbus.port), ("bare", bare_port)):
                    t0, c0 = time.perf_counter(), os.times()
                    if client == "pymodbus":
                        rate = await _py_window(workers[:n], port, 1, window_s)
                    else:
                        assert exe is not None
                        rate = await _c_window(exe, port, 1, n, window_s)
                    c1, wall = os.times(), time.perf_counter() - t0
                    res.setdefault((client, n, server), []).append(rate)
                    # this process serves both servers; the idle one costs next to nothing
                    used = (c1.user - c0.user) + (c1.system - c0.system)
                    cpu.setdefault((client, n, server), []).append(used / (rate * wall) * 1e6)
    finally:
        for w in workers:
            w.close()
        tmp.cleanup()
        await bare.shutdown()
        await gw.stop()
        inj.close()
    s = Summary.of
    for client, n in setups:
        g, b = res[(client, n, "gw")], res[(client, n, "bare")]
        ratio = s(paired_ratios(g, b))
        sec.rows.append(
            Row(
                f"requests/s, {n} {client} client{'s' if n > 1 else ''}",
                s(g),
                "bare pymodbus server",
                s(b),
                ratio,
                ">= 0.9x bare",
                ratio.median >= 0.9,
            )  # fmt: skip
        )
    return sec
