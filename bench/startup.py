"""Benchmark 5, start-up: ``canopen-gateway run -c <demo config>`` to its first Modbus answer.

The demo config (config/demo.yaml: five simulated devices of every family) is copied with a
private virtual channel and free loopback ports. The clock runs from process start
(``subprocess.Popen``) to the first Modbus answer (the gateway's own unit 247, register 0: bus
state), and on to the first process value of a simulated node (SGH10 ``wire``, input registers
100-101: booted, configured by SDO, started, first TPDO decoded). Baselines in the same run:
``python -c pass``, ``python -c "import canopen_gateway.app"`` and a bare pymodbus server process to its
first answer. Requests are raw Modbus TCP frames on a plain socket (no client library to load).

Imports: bench.*, yaml, the standard library (the gateway runs in a subprocess).
"""

from __future__ import annotations

import os
import pathlib
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time

import yaml

from bench.report import Row, Section
from bench.rig import free_port, unique_channel
from bench.stats import Summary, paired_ratios

REPO = pathlib.Path(__file__).resolve().parent.parent
DEMO = REPO / "config" / "demo.yaml"
GATEWAY_UNIT = 247  # modbus.gateway_unit_id default
FC_READ_INPUT = 4

BARE_SERVER = """
import asyncio, sys
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice
async def main():
    dev = SimDevice(id=0, simdata=[SimData(0, count=103, datatype=DataType.REGISTERS)])
    server = ModbusTcpServer(dev, address=("127.0.0.1", int(sys.argv[1])))
    await server.serve_forever()
asyncio.run(main())
"""


def modbus_read(
    port: int, unit: int, address: int, count: int, timeout_s: float = 0.5
) -> list[int] | None:
    """One FC4 request on a fresh connection; registers, or None (refused, exception, no answer)."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as s:
            s.sendall(struct.pack(">HHHBBHH", 1, 0, 6, unit, FC_READ_INPUT, address, count))
            head = s.recv(9)
            if len(head) < 9 or head[7] != FC_READ_INPUT:
                return None
            body = b""
            while len(body) < head[8]:
                chunk = s.recv(head[8] - len(body))
                if not chunk:
                    return None
                body += chunk
            return list(struct.unpack(f">{count}H", body[: 2 * count]))
    except OSError:
        return None


def wait_answer(
    port: int,
    unit: int,
    address: int,
    count: int,
    t0: float,
    timeout_s: float,
    proc: subprocess.Popen[bytes],
    ok=lambda regs: True,
) -> float:  # type: ignore[no-untyped-def]  # noqa: E501
    """Seconds from ``t0`` to the first answer that ``ok`` accepts (NaN on timeout or exit)."""
    deadline = t0 + timeout_s
    while time.perf_counter() < deadline:
        if proc.poll() is not None:
            return float("nan")
        regs = modbus_read(port, unit, address, count)
        if regs is not None and ok(regs):
            return time.perf_counter() - t0
        time.sleep(0.005)
    return float("nan")


def stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def demo_config(workdir: pathlib.Path) -> tuple[pathlib.Path, int]:
    raw = yaml.safe_load(DEMO.read_text(encoding="utf-8"))
    port = free_port()
    raw["can"]["channel"] = unique_channel("startup")
    raw["modbus"]["port"] = port
    raw["zenoh"]["listen"] = [f"tcp/127.0.0.1:{free_port()}"]
    if "health" in raw:
        raw["health"]["port"] = free_port()
    path = workdir / "demo.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    return path, port


def _wall(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(args, check=True, capture_output=True)
    return time.perf_counter() - t0


async def run(reps: int = 5, timeout_s: float = 20.0) -> Section:
    sec = Section(
        key="startup",
        title="5. Start-up: process start to first Modbus answer (demo config)",
        method=(
            f'{reps} repetitions, each: `python -c pass`, `python -c "import canopen_gateway.app"`, a '
            "bare pymodbus server process to its first answer, and `canopen-gateway run -c "
            "demo.yaml` (five simulated devices; private channel and ports) to its first "
            "Modbus answer and to the first process value of a simulated node. Raw Modbus TCP "
            "requests on a plain socket every 5 ms."
        ),
    )
    py = sys.executable
    exe = str(pathlib.Path(py).parent / "canopen-gateway")
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    res: dict[str, list[float]] = {k: [] for k in ("pass", "import", "bare", "gw", "gw_value")}
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        cfg_path, port = demo_config(pathlib.Path(tmp))
        for _rep in range(reps):
            res["pass"].append(_wall([py, "-c", "pass"]))
            res["import"].append(_wall([py, "-c", "import canopen_gateway.app"]))
            bare_port = free_port()
            t0 = time.perf_counter()
            proc = subprocess.Popen([py, "-c", BARE_SERVER, str(bare_port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
            try:
                res["bare"].append(wait_answer(bare_port, 1, 0, 1, t0, timeout_s, proc))
            finally:
                stop(proc)
            log = open(pathlib.Path(tmp) / "gateway.log", "wb")  # noqa: SIM115 - closed below
            t0 = time.perf_counter()
            proc = subprocess.Popen([exe, "run", "-c", str(cfg_path)], stdout=log, stderr=subprocess.STDOUT, env=env)  # fmt: skip
            try:
                res["gw"].append(wait_answer(port, GATEWAY_UNIT, 0, 1, t0, timeout_s, proc))
                res["gw_value"].append(wait_answer(port, 1, 100, 2, t0, timeout_s, proc))
            finally:
                stop(proc)
                log.close()
        if any(x != x for x in res["gw"]):  # NaN: never answered
            sec.notes.append(
                "The gateway did not answer within the time limit in some runs; its log: "
                + (pathlib.Path(tmp) / "gateway.log").read_text(errors="replace")[-800:]
            )
    s = Summary.of
    sec.rows = [
        Row("process start -> first Modbus answer (s)", s(res["gw"]), "bare pymodbus server",
            s(res["bare"]), s(paired_ratios(res["gw"], res["bare"])), "<= 1.5 s",
            s(res["gw"]).median <= 1.5, digits=3),
        Row("process start -> first node value on Modbus (s)", s(res["gw_value"]), "bare pymodbus server",
            s(res["bare"]), s(paired_ratios(res["gw_value"], res["bare"])), digits=3),
        Row("`python -c \"import canopen_gateway.app\"` (s)", s(res["import"]), "`python -c pass`",
            s(res["pass"]), s(paired_ratios(res["import"], res["pass"])), digits=3),
    ]  # fmt: skip
    return sec
