"""Client processes of the benchmarks: Zenoh subscriber, Modbus poller, Modbus load generator.

Each runs in its own process (multiprocessing, spawn: no fork of a process that has zenoh
threads), so it does not share the gateway's interpreter lock, as a PLC or a cloud client would
not. The parent drives it through a pipe with small commands; times are ``time.perf_counter()``
(CLOCK_MONOTONIC on Linux, the same clock in every process), so a time taken here can be
compared with a send time taken in the parent.

Imports: zenoh and pymodbus clients (inside the child functions), the standard library.
Nothing of the gateway.
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import os
import struct
import threading
import time
import traceback
from multiprocessing.connection import Connection
from typing import Any

_I32 = struct.Struct("<i")


class WorkerFailed(RuntimeError):
    pass


class Worker:
    """Parent side of a client process: ``call`` sends a command and waits for its answer."""

    def __init__(self, target: Any, *args: Any, name: str, start_timeout_s: float = 30.0):
        ctx = multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.name = name
        self.proc = ctx.Process(target=_serve, args=(target, child, *args), name=name, daemon=True)
        self.proc.start()
        child.close()
        self.info = self.recv(start_timeout_s)

    def send(self, *cmd: Any) -> None:
        self.conn.send(cmd)

    def recv(self, timeout_s: float) -> Any:
        if not self.conn.poll(timeout_s):
            raise TimeoutError(f"{self.name}: no answer within {timeout_s} s")
        kind, value = self.conn.recv()
        if kind == "error":
            raise WorkerFailed(f"{self.name} failed:\n{value}")
        return value

    def call(self, *cmd: Any, timeout_s: float = 60.0) -> Any:
        self.send(*cmd)
        return self.recv(timeout_s)

    async def acall(self, *cmd: Any, timeout_s: float = 60.0) -> Any:
        """``call`` without blocking the event loop (the gateway under test may run on it)."""
        return await asyncio.to_thread(self.call, *cmd, timeout_s=timeout_s)

    def close(self) -> None:
        if self.proc.is_alive():
            try:
                self.conn.send(("exit",))
            except (OSError, BrokenPipeError):
                pass
            self.proc.join(5.0)
            if self.proc.is_alive():
                self.proc.terminate()
                self.proc.join(2.0)
        self.conn.close()


def _serve(target: Any, conn: Connection, *args: Any) -> None:
    try:
        handler = target(*args)
        conn.send(("ok", getattr(handler, "info", None)))
        while True:
            cmd = conn.recv()
            if cmd[0] == "exit":
                break
            conn.send(("ok", getattr(handler, cmd[0])(*cmd[1:])))
        getattr(handler, "close", lambda: None)()
    except EOFError:
        pass
    except Exception:  # noqa: BLE001 - report any failure to the parent
        conn.send(("error", traceback.format_exc()))


# ---------------------------------------------------------------------- Zenoh subscriber
class ZenohSubscriber:
    """Subscribes key expressions; records (payload, arrival time) or just counts per key.

    ``subs`` is a list of (key expression, mode) with mode ``record`` (keep every sample) or
    ``count`` (count samples per key; a sample whose key equals ``probe_key`` is recorded too).
    """

    def __init__(self, endpoints: list[str], subs: list[tuple[str, str]], probe_key: str = ""):
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("connect/endpoints", json.dumps(endpoints))
        conf.insert_json5("listen/endpoints", "[]")
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.records: list[tuple[int, bytes, float]] = []
        self.counts: dict[str, int] = {}
        self.last_arrival = 0.0
        self._subs = []
        clock = time.perf_counter
        for idx, (key, mode) in enumerate(subs):
            if mode == "record":
                rec = self.records.append

                def on_sample(sample: Any, idx: int = idx, rec: Any = rec) -> None:
                    t = clock()
                    rec((idx, sample.payload.to_bytes(), t))
                    self.last_arrival = t

            else:
                counts = self.counts

                def on_sample(sample: Any, idx: int = idx, counts: dict[str, int] = counts) -> None:
                    t = clock()
                    k = str(sample.key_expr)
                    counts[k] = counts.get(k, 0) + 1
                    if k == probe_key:
                        self.records.append((idx, sample.payload.to_bytes(), t))
                    self.last_arrival = t

            self._subs.append(self.session.declare_subscriber(key, on_sample))
        self.info = {"subscribed": [k for k, _ in subs]}

    def wait(self, n_records: int, quiet_s: float, timeout_s: float) -> int:
        """Wait until ``n_records`` samples were recorded, or none came for ``quiet_s``."""
        deadline = time.perf_counter() + timeout_s
        while len(self.records) < n_records and time.perf_counter() < deadline:
            last = self.last_arrival
            if last and time.perf_counter() - last > quiet_s:
                break
            time.sleep(0.01)
        return len(self.records)

    def take(self, parse: list[str]) -> dict[str, Any]:
        """Recorded samples as (subscription index, value, arrival time) and the counts; clears.

        ``parse[idx]`` says how to read a payload: ``json`` (the "value" field), ``json_all``
        (the whole JSON object), ``i32`` (a little-endian int32).
        """
        recs = self.records[:]
        del self.records[: len(recs)]  # appends from zenoh threads go on at the end
        counts = dict(self.counts)
        self.counts.clear()
        out = []
        for idx, payload, t in recs:
            how = parse[idx]
            if how == "i32":
                value: Any = _I32.unpack_from(payload)[0]
            else:
                doc = json.loads(payload)
                value = doc if how == "json_all" else doc["value"]
            out.append((idx, value, t))
        t = os.times()
        return {
            "records": out,
            "counts": counts,
            "last_arrival": self.last_arrival,
            "cpu_s": t.user + t.system,  # of this process so far
            "at": time.perf_counter(),
        }

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self.session.close()


# ---------------------------------------------------------------------- Modbus poller
class ModbusPoller:
    """Polls input registers in a tight loop with pymodbus' AsyncModbusTcpClient and records
    the time every change was first seen."""

    info = None

    def poll(
        self, host: str, port: int, unit: int, address: int, count: int, duration_s: float
    ) -> dict[str, Any]:
        return asyncio.run(self._poll(host, port, unit, address, count, duration_s))

    async def _poll(
        self, host: str, port: int, unit: int, address: int, count: int, duration_s: float
    ) -> dict[str, Any]:
        from pymodbus.client import AsyncModbusTcpClient

        client = AsyncModbusTcpClient(host, port=port, timeout=2)
        await client.connect()
        clock = time.perf_counter
        changes: list[tuple[tuple[int, ...], float]] = []
        last: tuple[int, ...] | None = None
        polls = errors = 0
        rtts: list[float] = []
        end = clock() + duration_s
        try:
            while clock() < end:
                t_req = clock()
                rr = await client.read_input_registers(address, count=count, device_id=unit)
                t = clock()
                rtts.append(t - t_req)
                polls += 1
                if rr.isError():
                    errors += 1
                    continue
                regs = tuple(rr.registers)
                if regs != last:
                    changes.append((regs, t))
                    last = regs
        finally:
            client.close()
        rtts.sort()
        rtt_ms = {
            q: rtts[min(len(rtts) - 1, int(len(rtts) * q / 100))] * 1000.0 if rtts else float("nan")
            for q in (50, 99)
        }
        return {"changes": changes, "polls": polls, "errors": errors, "duration_s": duration_s,
                "rtt_ms": rtt_ms}  # fmt: skip


# ---------------------------------------------------------------------- Modbus load
class ModbusLoad:
    """Reads ``count`` input registers as fast as one synchronous pymodbus client can."""

    info = None

    def __init__(self) -> None:
        self._clients: dict[tuple[str, int], Any] = {}

    def _client(self, host: str, port: int) -> Any:
        from pymodbus.client import ModbusTcpClient

        c = self._clients.get((host, port))
        if c is None:
            c = ModbusTcpClient(host, port=port, timeout=2)
            if not c.connect():
                raise ConnectionError(f"cannot connect to {host}:{port}")
            self._clients[(host, port)] = c
        return c

    def run(
        self,
        host: str,
        port: int,
        unit: int,
        address: int,
        count: int,
        start_at: float,
        duration_s: float,
    ) -> dict[str, Any]:
        c = self._client(host, port)
        rr = c.read_input_registers(address, count=count, device_id=unit)  # warm, and check
        if rr.isError():
            raise RuntimeError(f"{host}:{port} unit {unit} answered {rr}")
        clock = time.perf_counter
        while clock() < start_at:
            time.sleep(0.001)
        n = errors = 0
        t0 = clock()
        end = t0 + duration_s
        read = c.read_input_registers
        while clock() < end:
            if read(address, count=count, device_id=unit).isError():
                errors += 1
            n += 1
        return {"requests": n, "errors": errors, "elapsed_s": clock() - t0}

    def close(self) -> None:
        for c in self._clients.values():
            c.close()


def start_subscriber(
    endpoints: list[str], subs: list[tuple[str, str]], probe_key: str = ""
) -> Worker:
    return Worker(ZenohSubscriber, endpoints, subs, probe_key, name="zenoh-subscriber")


def start_poller() -> Worker:
    return Worker(ModbusPoller, name="modbus-poller")


def start_load(n: int) -> list[Worker]:
    workers: list[Worker] = []
    threads = [
        threading.Thread(target=lambda: workers.append(Worker(ModbusLoad, name="modbus-load")))
        for _ in range(n)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return workers
