"""Benchmark 11, second part: the pair's take-over when the active member loses its bus, and the
standby's CPU, on a bus that says who sent every frame (``tests/pair_bus.py``'s ``PairBus``).

Two gateway processes (``canopen-gateway run``, one config; each gateway's own id, priority,
Modbus port and its member name on the bus, ``can.channel``, from the environment) and the
devices simulated in a third (``canopen-gateway simulate``, member ``devices``: an SGH10, an
AP05 and a POSI+ consuming the logical heartbeat), all ``interface: socketcand`` members of one
``PairBus`` in this process. Rounds alternate two faults of the active member:

- **cut**: its cable cut (its connection stays open; it hears nothing, nothing it sends
  arrives); its driver cannot notice;
- **unplug**: its adapter lost (the connection closed, reconnects refused); its driver notices.

Each round: both settle, CPU of both gateway processes over the same window (standby / active),
then the fault for ``hold_s``, then the cable mended / the adapter plugged and ``after_s`` of
watching. Measured at the relay (one clock, frames attributed): take-over = from the old active
member's last logical heartbeat (700h + 100) that reached the bus to the first the other member
sends that reaches it; what the faulted member sent meanwhile (logical heartbeats lost on its
cable); and after the repair: who masters the bus (a fail-back onto the member that was cut
off), NMT commands and SDO requests the gateways sent (a reconfiguration of the devices).

Imports: bench.* (bench.pair: the config, the gateway processes), tests.pair_bus (the relay), the standard library (the gateways run in
subprocesses).
"""

from __future__ import annotations

import pathlib
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field

from bench.pair import IDS, LOGICAL, REPO, PairGateway, pair_config, wait_for
from bench.report import Row
from bench.rig import NMT_EC_BASE
from bench.startup import stop
from bench.stats import Summary, paired_ratios
from tests.pair_bus import PairBus

LOGICAL_HB = NMT_EC_BASE + LOGICAL
MEMBERS = {IDS[0]: "a", IDS[1]: "b"}
GATEWAYS = set(MEMBERS.values())


@dataclass
class FaultRound:
    """What one fault of the active member did."""

    fault: str  # "cut" or "unplug"
    victim: str  # the member that was active
    takeover_s: float | None  # None: the other member did not take over during the fault
    lost_heartbeats: int  # logical heartbeats the victim sent that reached no one
    failback: bool  # after the repair the victim masters the bus again
    nmt_after: int  # NMT commands (000h) the gateways sent after the repair
    sdo_after: int  # SDO requests (600h + id) the gateways sent after the repair
    settled: bool  # one member mastering the bus at the end of the round


@dataclass
class FaultResults:
    rounds: list[FaultRound] = field(default_factory=list)
    cpu_standby: list[float] = field(default_factory=list)
    cpu_active: list[float] = field(default_factory=list)


def _masters(bus: PairBus, since: float) -> set[str]:
    """Members whose logical heartbeat reached the bus since ``since`` (relay clock)."""
    out = set()
    for f in reversed(bus.frames):
        if f.t < since:
            break
        if f.cob_id == LOGICAL_HB and f.delivered:
            out.add(f.sender)
    return out


def _settled(bus: PairBus, window_s: float) -> str | None:
    """The one member mastering the bus over the last ``window_s``, else None."""
    masters = _masters(bus, time.monotonic() - window_s)
    return next(iter(masters)) if len(masters) == 1 else None


def _one_round(bus: PairBus, fault: str, hold_s: float, after_s: float) -> FaultRound:
    victim = _settled(bus, 0.5) or ""
    other = (GATEWAYS - {victim}).pop()
    mark = len(bus.frames)
    last = max((f.t for f in bus.frames[:mark] if f.sender == victim and f.cob_id == LOGICAL_HB
                and f.delivered), default=time.monotonic())  # fmt: skip
    (bus.cut if fault == "cut" else bus.unplug)(victim)
    time.sleep(hold_s)
    (bus.mend if fault == "cut" else bus.plug)(victim)
    repaired = len(bus.frames)
    time.sleep(after_s)
    during = bus.frames[mark:repaired]
    took = [f.t for f in during if f.sender == other and f.cob_id == LOGICAL_HB and f.delivered]
    after = [f for f in bus.frames[repaired:] if f.sender in GATEWAYS]
    final = _settled(bus, 1.0)
    return FaultRound(
        fault=fault,
        victim=victim,
        takeover_s=(took[0] - last) if took else None,
        lost_heartbeats=sum(
            1 for f in during if f.sender == victim and f.cob_id == LOGICAL_HB and not f.delivered
        ),
        failback=final == victim and bool(took),
        nmt_after=sum(1 for f in after if f.cob_id == 0x000),
        sdo_after=sum(1 for f in after if 0x601 <= f.cob_id <= 0x67F),
        settled=final is not None,
    )


def measure(
    rounds: int = 6, hold_s: float = 3.0, after_s: float = 6.0, cpu_window_s: float = 3.0
) -> FaultResults:
    """Run the scenario (``rounds`` faults, cut and unplug alternating); see the docstring."""
    out = FaultResults()
    with tempfile.TemporaryDirectory(prefix="bench-pair-faults-") as tmp, PairBus() as bus:
        workdir = pathlib.Path(tmp)
        cfg = pair_config(workdir, bus.can_section("devices"))
        sim = subprocess.Popen(
            [sys.executable, "-m", "gateway", "simulate", "-c", str(cfg)],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        gws: dict[str, PairGateway] = {}
        try:
            for (node_id, member), prio in zip(MEMBERS.items(), (0, 1), strict=True):
                env = {"CANOPEN_GATEWAY__CAN__CHANNEL": member}
                gws[member] = PairGateway(workdir, cfg, node_id, prio, 0, extra_env=env)
                wait_for(lambda m=member: any(f.sender == m for f in bus.frames[-200:]), 30,
                      f"gateway {member} on the bus")  # fmt: skip
                wait_for(lambda: _settled(bus, 1.0) == "a", 30, "gateway a mastering the bus")
            for i in range(rounds):
                wait_for(lambda: _settled(bus, 1.0) is not None, 20, "one member mastering the bus")
                time.sleep(1.0)  # both settled: the standby's start-up is not counted
                active = _settled(bus, 0.5) or "a"
                standby = (GATEWAYS - {active}).pop()
                a0, s0 = gws[active].cpu_s(), gws[standby].cpu_s()
                time.sleep(cpu_window_s)
                a1, s1 = gws[active].cpu_s(), gws[standby].cpu_s()
                out.cpu_active.append(100 * (a1 - a0) / cpu_window_s)
                out.cpu_standby.append(100 * (s1 - s0) / cpu_window_s)
                r = _one_round(bus, ("cut", "unplug")[i % 2], hold_s, after_s)
                out.rounds.append(r)
                if not r.settled:
                    break  # two masters (or none) for good: the next round would measure nothing
        finally:
            for gw in gws.values():
                gw.stop()
            stop(sim)
    return out


def rows_and_notes(res: FaultResults) -> tuple[list[Row], list[str]]:
    """The section's rows and notes for these results."""
    s = Summary.of
    rows, notes = [], []
    for fault, what in (("cut", "cable cut"), ("unplug", "adapter lost")):
        rs = [r for r in res.rounds if r.fault == fault]
        took = [1000 * r.takeover_s for r in rs if r.takeover_s is not None]
        rows.append(Row(
            f"take-over after the active member's {what}: its last logical heartbeat on the bus "
            "-> the other's first (ms)", s(took), target="< 1000 ms, every round",
            met=bool(rs) and len(took) == len(rs) and max(took) < 1000, digits=0,
        ))  # fmt: skip
        if rs:
            notes.append(
                f"{what} ({len(rs)} rounds): taken over in {len(took)}; the faulted member sent "
                f"{sum(r.lost_heartbeats for r in rs)} logical heartbeats that reached no one; after "
                f"the repair: fail-back onto it in {sum(r.failback for r in rs)}, "
                f"{sum(r.nmt_after for r in rs)} NMT commands and {sum(r.sdo_after for r in rs)} SDO "
                f"requests from the gateways, one member mastering the bus at the end in "
                f"{sum(r.settled for r in rs)}."
            )
    if res.cpu_active:
        rows.append(Row(
            "standby gateway CPU on the socketcand test bus (% of a core)", s(res.cpu_standby),
            "active gateway", s(res.cpu_active), s(paired_ratios(res.cpu_standby, res.cpu_active)),
            "standby / active <= 1.0",
            s(paired_ratios(res.cpu_standby, res.cpu_active)).median <= 1.0, digits=1,
        ))  # fmt: skip
    return rows, notes


if __name__ == "__main__":  # a quick look: python -m bench.pair_faults [rounds]
    result = measure(rounds=int(sys.argv[1]) if len(sys.argv) > 1 else 2)
    for row in rows_and_notes(result)[0]:
        print(row)
    for note in rows_and_notes(result)[1]:
        print(note)
    for r in result.rounds:
        print(r)
