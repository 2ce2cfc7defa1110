"""Benchmark 11, second part: the pair's take-over when the active member loses its bus, and the
standby's CPU, on a bus that says who sent every frame (``tests/pair_bus.py``'s ``PairBus``).

Two gateway processes (``canopen-gateway run``, one config; each gateway's own id, priority,
Modbus port and its member name on the bus, ``can.channel``, from the environment) and the
devices simulated in a third (``canopen-gateway simulate``, member ``devices``: an SGH10, an
AP05 and a POSI+ consuming the logical heartbeat), all ``interface: socketcand`` members of one
``PairBus`` in this process. Rounds take four faults of the active member in turn:

- **cut**: its cable cut (its connection stays open; it hears nothing, nothing it sends
  arrives); its driver cannot notice;
- **unplug**: its adapter lost (the connection closed, reconnects refused); its driver notices;
- **mute**: its transmitter fails silently (it hears, nothing it sends arrives): it must notice
  by itself (its 75h unanswered) when the other takes over;
- **sigterm**: stopped (a rolling update): it hands the bus over to the standby; the pauses of
  the logical heartbeat, SYNC and the RPDOs across the stop are measured; then started again.

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
from collections.abc import Callable
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

    fault: str  # "cut", "unplug", "mute" or "sigterm"
    victim: str  # the member that was active
    takeover_s: float | None  # None: the other member did not take over during the fault
    lost_heartbeats: int  # logical heartbeats the victim sent that reached no one
    failback: bool  # after the repair the victim masters the bus again
    nmt_after: int  # NMT commands (000h) the gateways sent after the repair
    sdo_after: int  # SDO requests (600h + id) the gateways sent after the repair
    settled: bool  # one member mastering the bus at the end of the round
    #: the longest pause of the logical heartbeat, SYNC and the RPDOs around the fault (ms)
    gaps_ms: dict[str, float] = field(default_factory=dict)


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


#: the AP05's RPDO keep-alive (its profile's ``keepalive_ms``): the only RPDO sent periodically
KEEPALIVE_MS = 500
#: the frames whose pauses a hand-over is judged by: the logical heartbeat, SYNC, the RPDOs
GAP_COBS = {"logical heartbeat": {LOGICAL_HB}, "SYNC": {0x080},
            "RPDO": {0x200 + n for n in (1, 2, 3)} | {0x300 + n for n in (1, 2, 3)}}  # fmt: skip


def _gaps_ms(bus: PairBus, since: int, at: float) -> dict[str, float]:
    """The pause of each kind of frame across ``at``: from its last delivered frame before to
    the first after (the RPDOs: each COB-ID, the longest)."""
    out: dict[str, float] = {}
    for name, cobs in GAP_COBS.items():
        worst = 0.0
        for cob in cobs:
            stamps = [f.t for f in bus.frames[since:] if f.cob_id == cob and f.delivered]
            before = [t for t in stamps if t <= at]
            after = [t for t in stamps if t > at]
            if before and after:
                worst = max(worst, after[0] - before[-1])
        out[name] = 1000 * worst
    return out


def _one_round(
    bus: PairBus, fault: str, hold_s: float, after_s: float, restart: Callable[[str], None]
) -> FaultRound:
    victim = _settled(bus, 0.5) or ""
    other = (GATEWAYS - {victim}).pop()
    mark = len(bus.frames)
    last = max((f.t for f in bus.frames[:mark] if f.sender == victim and f.cob_id == LOGICAL_HB
                and f.delivered), default=time.monotonic())  # fmt: skip
    at = time.monotonic()
    faults: dict[str, tuple[Callable[[str], None], Callable[[str], None]]] = {
        "cut": (bus.cut, bus.mend), "unplug": (bus.unplug, bus.plug), "mute": (bus.mute, bus.unmute),
        "sigterm": (lambda m: None, restart),
    }  # fmt: skip
    if fault == "sigterm":
        restart(f"stop {victim}")
    faults[fault][0](victim)
    time.sleep(hold_s)
    faults[fault][1](victim)
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
        gaps_ms=_gaps_ms(bus, max(0, mark - 200), at),
    )


FAULTS = ("cut", "unplug", "mute", "sigterm")


def measure(
    rounds: int = 8, hold_s: float = 3.0, after_s: float = 6.0, cpu_window_s: float = 3.0
) -> FaultResults:
    """Run the scenario (``rounds`` faults, cut, unplug, mute and SIGTERM in turn); see the
    docstring."""
    out = FaultResults()
    with tempfile.TemporaryDirectory(prefix="bench-pair-faults-") as tmp, PairBus() as bus:
        workdir = pathlib.Path(tmp)
        cfg = pair_config(workdir, bus.can_section("devices"))
        sim = subprocess.Popen(
            [sys.executable, "-m", "canopen_gateway", "simulate", "-c", str(cfg)],
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
                starts = {"n": 0}

                def restart(what: str, starts: dict[str, int] = starts, i: int = i) -> None:
                    if what.startswith("stop "):  # SIGTERM: a planned hand-over
                        gws[what[5:]].stop()
                        return
                    starts["n"] += 1
                    node_id = next(k for k, v in MEMBERS.items() if v == what)
                    env = {"CANOPEN_GATEWAY__CAN__CHANNEL": what}
                    gws[what] = PairGateway(workdir, cfg, node_id, IDS.index(node_id), 100 * i + starts["n"],
                                            extra_env=env)  # fmt: skip

                r = _one_round(bus, FAULTS[i % len(FAULTS)], hold_s, after_s, restart)
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
    for fault, what in (("cut", "cable cut"), ("unplug", "adapter lost"), ("mute", "transmitter muted"),
                        ("sigterm", "SIGTERM (planned hand-over)")):  # fmt: skip
        rs = [r for r in res.rounds if r.fault == fault]
        took = [1000 * r.takeover_s for r in rs if r.takeover_s is not None]
        rows.append(Row(
            f"take-over after the active member's {what}: its last logical heartbeat on the bus "
            "-> the other's first (ms)", s(took), target="< 1000 ms, every round",
            met=bool(rs) and len(took) == len(rs) and max(took) < 1000, digits=0,
        ))  # fmt: skip
        if fault == "sigterm" and rs:
            for kind in GAP_COBS:
                gaps = [r.gaps_ms[kind] for r in rs if r.gaps_ms.get(kind)]
                period_ms = KEEPALIVE_MS if kind == "RPDO" else 100  # heartbeat_ms, sync_period_ms
                rows.append(Row(
                    f"planned hand-over (SIGTERM of the active member): longest pause of the {kind} "
                    f"(ms; its period {period_ms} ms)", s(gaps), target="<= one period + 100 ms",
                    met=bool(gaps) and max(gaps) <= period_ms + 100, digits=0,
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
