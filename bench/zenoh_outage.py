"""Benchmark 7, a router outage: the Zenoh router is down for 10 s while 100 EMCY events are
raised and values change; what does a subscriber have once the router is back?

Rig (one process, as the tests do): a router-mode eclipse-zenoh session on a free loopback
port, the gateway (peer, connected to the router; an SGH10 simulated on a private virtual bus,
position ramping) and two client sessions connected to the router: an ``AdvancedSubscriber``
(history with late-publisher detection, recovery by heartbeat: the recipe of docs/zenoh.md) and
a plain subscriber, both on ``canopen/bench/**``. Per repetition: the router is closed, 100 EMCY
frames are raised by the simulated device, one every 100 ms (50 errors raised and cleared), then
after 10 s a new router opens on the same endpoint. Measured from that moment: when the
advanced subscriber has all 100 events (and whether in order, by their ``seq``), and when it
has, for every value key, a sample at least as new as the last one the gateway had published when
the router came back (0 when it already had it); and how many of the 100 the plain subscriber got.

``python -m bench.zenoh_outage`` (or ``python -m bench outage``) prints the section.

Imports: bench.*, gateway.*, zenoh, the standard library.
"""

from __future__ import annotations

import asyncio
import json
import logging
import queue
import time
from typing import Any

import zenoh
import zenoh.ext

from bench.report import Row, Section, render_section
from bench.rig import free_port, gateway_of, unique_channel
from bench.stats import Summary
from canopen_gateway.config import parse_config

REPS = 3
OUTAGE_S = 10.0
EVENTS = 100
PREFIX = "canopen/bench"


def _conf(mode: str, endpoint: str) -> zenoh.Config:
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    key = "listen/endpoints" if mode == "router" else "connect/endpoints"
    c.insert_json5(key, json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


class _Collector:
    """Samples of one subscriber with their arrival time (perf_counter)."""

    def __init__(self) -> None:
        self.q: queue.SimpleQueue[tuple[float, str, Any]] = queue.SimpleQueue()
        self.samples: list[tuple[float, str, Any]] = []

    def __call__(self, s: zenoh.Sample) -> None:
        self.q.put((time.perf_counter(), str(s.key_expr), json.loads(s.payload.to_bytes())))

    def pull(self) -> list[tuple[float, str, Any]]:
        while True:
            try:
                self.samples.append(self.q.get_nowait())
            except queue.Empty:
                return self.samples


async def _one(rep: int) -> dict[str, float]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(_conf("router", endpoint))
    cfg = parse_config(
        {
            "gateway": {"name": "bench"},
            "can": {"interface": "virtual", "channel": unique_channel("outage")},
            "master": {"heartbeat_ms": 200, "sync_period_ms": 50},
            "nodes": [{"name": "wire", "node_id": 1, "profile": "sgh10"}],
            "modbus": {"enabled": False},
            "zenoh": {"listen": [], "connect": [endpoint]},
            "simulate": {"nodes": "all", "motion": {"wire": {"kind": "ramp", "speed": 300}}},
        },
        environ={},
    )
    gw = gateway_of(cfg)
    await gw.start()
    adv_s = zenoh.open(_conf("client", endpoint))
    plain_s = zenoh.open(_conf("client", endpoint))
    adv, plain = _Collector(), _Collector()
    sub = zenoh.ext.declare_advanced_subscriber(
        adv_s,
        f"{PREFIX}/**",
        adv,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
        subscriber_detection=True,
    )
    psub = plain_s.declare_subscriber(f"{PREFIX}/**", plain)
    try:
        node = gw.image.nodes["wire"]
        deadline = time.monotonic() + 15
        while not node.usable() and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        await asyncio.sleep(1.0)  # subscribers settled, values flowing
        emcy_key = f"{PREFIX}/wire/emcy"
        seq0 = max((b["seq"] for _, k, b in adv.pull() if k == emcy_key), default=0)

        router.close()
        assert gw.sim is not None
        sim = gw.sim.nodes["wire"]
        t_down = time.perf_counter()
        for i in range(EVENTS):
            if i % 2 == 0:
                gw.sim.runner.call(lambda now: sim.raise_emcy(0xFF05, 0x80, now=now))
            else:
                gw.sim.runner.call(lambda now: sim.clear_emcy(0xFF05, now=now))
            await asyncio.sleep(max(0.0, t_down + (i + 1) * OUTAGE_S / EVENTS - time.perf_counter()))
        await asyncio.sleep(max(0.0, t_down + OUTAGE_S - time.perf_counter()))
        router = zenoh.open(_conf("router", endpoint))
        t_up = time.perf_counter()
        # what the gateway has published last (unchanged values are not republished)
        latest = {sp.key: sp.last_seq for sp in gw.zenoh.pubs.values()}  # type: ignore[union-attr]

        t_events = t_values = float("nan")
        limit = t_up + 30
        while time.perf_counter() < limit:
            got = adv.pull()
            events = [(t, b["seq"]) for t, k, b in got if k == emcy_key and b["seq"] > seq0]
            if len(events) >= EVENTS and t_events != t_events:
                t_events = max(t for t, _ in events[:EVENTS]) - t_up
            newest: dict[str, tuple[float, int]] = {}
            for t, k, b in got:
                if k in latest and b.get("seq") is not None and b["seq"] >= latest[k]:
                    newest.setdefault(k, (t, b["seq"]))
            if len(newest) == len(latest) and t_values != t_values:
                t_values = max(0.0, max(t for t, _ in newest.values()) - t_up)
            if t_events == t_events and t_values == t_values:
                break
            await asyncio.sleep(0.01)
        got = adv.pull()
        seqs = [b["seq"] for _, k, b in got if k == emcy_key and b["seq"] > seq0]
        plain_seqs = [b["seq"] for _, k, b in plain.pull() if k == emcy_key and b["seq"] > seq0]
        return {
            "received": float(len(set(seqs) & set(range(seq0 + 1, seq0 + EVENTS + 1)))),
            "in_order": float(seqs[:EVENTS] == list(range(seq0 + 1, seq0 + EVENTS + 1))),
            "t_events": t_events,
            "t_values": t_values,
            "plain": float(len(set(plain_seqs) & set(range(seq0 + 1, seq0 + EVENTS + 1)))),
            "values": float(len(latest)),
        }
    finally:
        sub.undeclare()
        psub.undeclare()
        adv_s.close()
        plain_s.close()
        await gw.stop()
        router.close()


async def run() -> Section:
    logging.getLogger("gateway").setLevel(logging.ERROR)
    results = []
    for rep in range(REPS):
        results.append(await _one(rep))

    def s(key: str) -> Summary:
        return Summary.of([r[key] for r in results])

    rows = [
        Row(f"EMCY events received by the AdvancedSubscriber (of {EVENTS})", s("received"),
            target=f"{EVENTS}", met=all(r["received"] == EVENTS for r in results)),
        Row("... in order (1 = every repetition in seq order)", s("in_order"), target="1",
            met=all(r["in_order"] == 1 for r in results)),
        Row(f"s from the router's return to all {EVENTS} events", s("t_events"), digits=2,
            target="<= 5 s", met=all(r["t_events"] <= 5 for r in results)),
        Row("s from the router's return to the latest value of every signal", s("t_values"),
            digits=2, target="<= 5 s", met=all(r["t_values"] <= 5 for r in results)),
        Row(f"EMCY events a plain subscriber received (of {EVENTS})", s("plain")),
    ]  # fmt: skip
    notes = [
        f"{int(results[0]['values'])} value keys; zenoh.history defaults (1,000 samples per "
        "event key, the last sample per value key, heartbeat 500 ms).",
        "A plain subscriber gets nothing of the outage: Zenoh keeps no sample for it. The "
        "advanced publishers' caches are in the gateway's memory: a gateway restart loses them.",
    ]
    return Section(
        key="outage",
        title="7. Router outage: events and values for AdvancedSubscriber clients",
        method=__doc__.split("\n\n")[1].replace("\n", " ") if __doc__ else "",
        rows=rows,
        notes=notes,
    )


def main() -> None:
    logging.basicConfig(level=logging.ERROR)
    sec = asyncio.run(run())
    print("\n".join(render_section(sec)))


if __name__ == "__main__":
    main()
