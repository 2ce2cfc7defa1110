"""Benchmark 11, a hot-standby pair: the take-over time and the standby's CPU.

Two gateway processes (``canopen-gateway run``, one config, each gateway's own id, priority and
Modbus port from the environment, as the compose example does) and the devices simulated in a
third process (``canopen-gateway simulate``: an SGH10, an AP05 and a POSI+ that consumes the
logical master's heartbeat, 1016h, 1000 ms) on one python-can-remote bus; ``heartbeat_ms: 100``
and the default take-over timings (docs/redundancy.md). Repeatedly the active gateway is killed
(SIGKILL) and, once the standby has taken over, started again (it joins as standby): the roles
alternate, so half the take-overs are by the gateway of priority 1 (node 102: slot 404 ms) and
half by the one of priority 0 (node 101: slot 202 ms).

Take-over time: from the old active gateway's last logical heartbeat (700h + 100) to the new
one's first, from the bus timestamps an observer connection receives (the relay's clock).
CPU: process CPU (``/proc/PID/stat`` utime + stime) of the standby and of the active gateway
over the same window, once per round while both run.

Then the same pair on a bus that attributes every frame to its sender (``bench.pair_faults``):
the take-over after the active member's cable is cut and after its adapter is lost, what the
pair does when the member comes back, and the standby / active CPU ratio there.

Imports: bench.*, tests.helpers (the python-can-remote server), python-can, yaml, the standard
library (the gateways run in subprocesses).
"""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import IO, Any

import can
import yaml

from bench.report import Row, Section
from bench.rig import NMT_EC_BASE, free_port
from bench.startup import stop
from bench.stats import Summary, paired_ratios
from tests.helpers import port_open, start_can_remote

REPO = pathlib.Path(__file__).resolve().parent.parent
LOGICAL = 100
IDS = (101, 102)  # priority 0, priority 1
HB_MS = 100
CONSUMER_MS = 1000
EMCY_BASE = 0x080  # CiA 301 7.3.5: EMCY 80h + node id
EMCY_HEARTBEAT_LOST = 0x8130  # CiA 301 / POSI+ manual 002 ch. 4
TICKS_S = os.sysconf("SC_CLK_TCK")


class _Heard(can.Listener):
    """Bus timestamps of the logical heartbeat; EMCY 8130h and NMT frames counted."""

    def __init__(self) -> None:
        self.logical: list[float] = []
        self.emcy_8130 = 0
        self.nmt = 0
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        cob = msg.arbitration_id
        with self.lock:
            if cob == NMT_EC_BASE + LOGICAL:
                self.logical.append(msg.timestamp)
            elif cob == 0x000:
                self.nmt += 1
            elif EMCY_BASE < cob <= EMCY_BASE + 127 and int.from_bytes(msg.data[:2], "little") == EMCY_HEARTBEAT_LOST:
                self.emcy_8130 += 1

    def stamps(self) -> list[float]:
        with self.lock:
            return list(self.logical)


class PairGateway:
    """One gateway process of the pair; its log (stdout and stderr) in a file."""

    def __init__(
        self, workdir: pathlib.Path, cfg: pathlib.Path, node_id: int, priority: int, round_: int,
        extra_env: dict[str, str] | None = None,
    ) -> None:  # fmt: skip
        self.node_id = node_id
        self.log_path = workdir / f"gw{node_id}-{round_}.log"
        env = {
            **os.environ,
            "CANOPEN_GATEWAY__MASTER__REDUNDANCY__NODE_ID": str(node_id),
            "CANOPEN_GATEWAY__MASTER__REDUNDANCY__PRIORITY": str(priority),
            "CANOPEN_GATEWAY__MODBUS__PORT": str(free_port()),
            **(extra_env or {}),
        }
        self._log: IO[bytes] = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "canopen_gateway", "run", "-c", str(cfg), "--no-simulate", "--log-level", "info"],
            cwd=REPO, env=env, stdout=self._log, stderr=subprocess.STDOUT,
        )  # fmt: skip

    def said(self, text: str) -> bool:
        return text in self.log_path.read_text(errors="replace")

    def cpu_s(self) -> float:
        fields = pathlib.Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICKS_S  # utime, stime (proc(5) fields 14, 15)

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        self._log.close()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


def wait_for(cond: Any, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} within {timeout_s} s")
        time.sleep(0.02)


def pair_config(workdir: pathlib.Path, can: dict[str, Any]) -> pathlib.Path:
    """The pair's one config file (each member's own id from its environment) on bus ``can``."""
    raw: dict[str, Any] = {
        "gateway": {"name": "pair"},
        "can": can,
        "master": {
            "node_id": LOGICAL,
            "heartbeat_ms": HB_MS,
            "sync_period_ms": 100,
            "heartbeat_timeout_multiple": 5,
            "redundancy": {"node_id": IDS[0]},
        },
        "nodes": [
            {"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 200},
            {"name": "display", "node_id": 2, "profile": "ap05", "heartbeat_ms": 200},
            {"name": "enc", "node_id": 3, "profile": "posi_plus", "heartbeat_ms": 200,
             "sdo": [{"object": "0x1016:01", "value": (LOGICAL << 16) | CONSUMER_MS}]},  # CiA 301 7.5.2.15
        ],  # fmt: skip
        "modbus": {"port": 0},
        "zenoh": {"enabled": False},
        "simulate": {"nodes": "all"},
    }
    path = workdir / "pair.yaml"
    path.write_text(yaml.safe_dump(raw), encoding="utf-8")
    return path


async def run(
    kills: int = 20, cpu_window_s: float = 3.0, settle_s: float = 2.0, fault_rounds: int = 8
) -> Section:
    sec = Section(
        key="pair",
        title="11. A hot-standby pair: take-over time and the standby's CPU",
        method=(
            f"Two `canopen-gateway run` processes of one config (own id and priority from the "
            f"environment) and `canopen-gateway simulate` (SGH10, AP05, POSI+ consuming the logical "
            f"heartbeat with 1016h = {CONSUMER_MS} ms) on one python-can-remote bus; `heartbeat_ms: "
            f"{HB_MS}`, default take-over timings. {kills} rounds: the active gateway is killed "
            "(SIGKILL); take-over = bus time from its last logical heartbeat (700h + 100) to the "
            "new active one's first, at an observer connection; then the killed one starts again "
            "and joins as standby (the roles alternate). CPU: `/proc/PID/stat` utime + stime of "
            f"both gateways over the same {cpu_window_s:.0f} s window each round, "
            f"{settle_s:.0f} s after the standby joined. Then {fault_rounds} rounds on a "
            "socketcand bus that attributes every frame to its sender (`tests/pair_bus.py`; "
            "each gateway and the simulated devices a member of it): the active member's cable "
            "cut (its connection open, nothing it sends arrives, it hears nothing), its adapter "
            "lost (the connection closed, reconnects refused), its transmitter muted (it hears, "
            "nothing it sends arrives, its driver unaware) or SIGTERM (a planned hand-over, then "
            "started again), in turn, for 3 s, then repaired and watched for 6 s; take-over = "
            "relay time from its last logical heartbeat that reached the bus to the other "
            "member's first; at the SIGTERM the longest pause of the logical heartbeat, SYNC and "
            "the RPDOs across it; CPU of both gateways over the same 3 s window before each fault."
        ),
    )
    port = free_port()
    takeover_s: dict[int, list[float]] = {i: [] for i in IDS}
    cpu_standby: list[float] = []
    cpu_active: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench-pair-") as tmp:
        workdir = pathlib.Path(tmp)
        cfg = pair_config(workdir, {"interface": "remote", "channel": f"ws://127.0.0.1:{port}/"})
        relay = start_can_remote(port, f"pair{port}")
        gateways: dict[int, PairGateway] = {}
        sim = None
        bus = None
        notifier = None
        try:
            wait_for(lambda: port_open(port), 10, "the python-can-remote relay listens")
            bus = can.Bus(interface="remote", channel=f"ws://127.0.0.1:{port}/")
            heard = _Heard()
            notifier = can.Notifier(bus, [heard])
            sim = subprocess.Popen(
                [sys.executable, "-m", "canopen_gateway", "simulate", "-c", str(cfg)],
                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )  # fmt: skip
            priority = {IDS[0]: 0, IDS[1]: 1}
            active = PairGateway(workdir, cfg, IDS[0], 0, 0)
            gateways[IDS[0]] = active
            wait_for(lambda: active.said("pair: negotiating -> active"), 30, "the first gateway active")
            wait_for(lambda: active.said("node enc: configuring -> operational"), 30, "the devices configured")
            standby = PairGateway(workdir, cfg, IDS[1], 1, 0)
            gateways[IDS[1]] = standby
            wait_for(lambda: standby.said("pair: listening -> standby"), 30, "the second gateway standby")
            nmt_before = heard.nmt
            for round_ in range(1, kills + 1):
                # CPU of both over the same window, both running and settled (the standby has
                # just started: its start-up is not counted)
                time.sleep(settle_s)
                a0, s0 = active.cpu_s(), standby.cpu_s()
                time.sleep(cpu_window_s)
                a1, s1 = active.cpu_s(), standby.cpu_s()
                cpu_active.append(100 * (a1 - a0) / cpu_window_s)
                cpu_standby.append(100 * (s1 - s0) / cpu_window_s)
                before = len(heard.stamps())
                active.kill()
                wait_for(lambda gw=standby: gw.said("pair: negotiating -> active"), 10, "the standby takes over")
                wait_for(lambda b=before: len(heard.stamps()) >= b + 3, 5, "the new active one's heartbeats")
                stamps = heard.stamps()[max(0, before - 3) :]
                takeover_s[standby.node_id].append(max(y - x for x, y in zip(stamps, stamps[1:], strict=False)))
                killed = active.node_id
                active = standby
                standby = PairGateway(workdir, cfg, killed, priority[killed], round_)
                gateways[killed] = standby
                wait_for(lambda gw=standby: gw.said("pair: listening -> standby"), 30, "the restarted gateway standby")
            nmt_after = heard.nmt
            emcy = heard.emcy_8130
        finally:
            for gw in gateways.values():
                gw.stop()
            if notifier is not None:
                notifier.stop()
            if bus is not None:
                bus.shutdown()
            for proc in (sim, relay):
                if proc is not None:
                    stop(proc)
    s = Summary.of
    every = takeover_s[IDS[0]] + takeover_s[IDS[1]]
    sec.rows = [
        Row("take-over: last logical heartbeat -> first of the new active one (ms), all kills",
            s([1000 * x for x in every]), target="< 1000 ms (docs/redundancy.md)",
            met=max(every) < 1.0, digits=0),
        Row(f"  by the standby of priority 1 (node {IDS[1]}, slot 404 ms)",
            s([1000 * x for x in takeover_s[IDS[1]]]), digits=0),
        Row(f"  by the standby of priority 0 (node {IDS[0]}, slot 202 ms)",
            s([1000 * x for x in takeover_s[IDS[0]]]), digits=0),
        Row("standby gateway CPU (% of a core)", s(cpu_standby), "active gateway", s(cpu_active),
            s(paired_ratios(cpu_standby, cpu_active)), "standby <= active",
            s(cpu_standby).median <= s(cpu_active).median, digits=1),
    ]  # fmt: skip
    sec.notes.append(
        f"Over the {kills} take-overs: {emcy} EMCY 8130h (heartbeat consumer of the POSI+ "
        f"expired), {nmt_after - nmt_before} NMT commands on the bus."
    )
    from bench import pair_faults  # it builds on this module's gateway process

    rows, notes = pair_faults.rows_and_notes(pair_faults.measure(rounds=fault_rounds))
    sec.rows += rows
    sec.notes += notes
    return sec
