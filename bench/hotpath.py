"""Where the time of one TPDO goes: the hot path taken apart, stage by stage, in microseconds.

Each stage is called directly in a loop on prebuilt frames (one thread, no contention, 20,000
calls per repetition) inside a started gateway with one SGH10 node: python-can ``recv`` of a
queued frame, the codec's ``decode``, the TPDO handler without listeners (decode + process
image), the Zenoh bridge's share for one frame with ``publish: every`` (2 signals), its parts
(payload + JSON, the template ``payloads.value_json``, ``put`` with and without a zenoh
timestamp), and the hop of a control frame (heartbeat, EMCY) to the event loop: one
``call_soon_threadsafe`` per frame, and the master's inbox (``Master._post``) when frames come
while the loop is busy. The bare listener's
``struct.unpack_from`` into a dict is the baseline of the decode stages. The sampled profiles
(py-spy) behind the findings are described in RESULTS.md, not taken here.

Imports: bench.*, gateway (through bench.rig), python-can.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from bench.report import Row, Section
from bench.rig import SGH10_TPDO, Injector, bench_config, bench_node, start_gateway, tpdo_frames
from bench.stats import Summary, paired_ratios
from canopen_gateway.zenoh_bridge.payloads import value_json, value_payload

N_CALLS = 20_000


def per_call_us(fn: Callable[[int], Any], n: int = N_CALLS) -> float:
    t0 = time.perf_counter()
    for i in range(n):
        fn(i)
    return (time.perf_counter() - t0) / n * 1e6


async def run(reps: int = 5) -> Section:
    sec = Section(
        key="hotpath",
        title="6. Hot path, stage by stage (us per call, no contention)",
        method=(
            f"Each stage called {N_CALLS:,} times in a loop on prebuilt frames, {reps} "
            "repetitions, inside a started gateway (one SGH10 node, `publish: every`); one "
            "thread, so these are costs without interpreter-lock contention. The bare "
            "listener's `struct.unpack_from` into a dict is the baseline of the decode stages."
        ),
    )
    cfg = bench_config([bench_node("n1", 1)], "hotpath")
    inj = Injector(cfg.can.channel)
    gw = await start_gateway(cfg, inj, [1])
    assert gw.zenoh is not None
    bridge: Any = gw.zenoh
    frames = tpdo_frames(1, range(N_CALLS))
    handler = gw.driver.handlers[frames[0].arbitration_id]
    rt = gw.master.nodes["n1"]
    codec = rt.tpdos[0]
    node = gw.image.nodes["n1"]
    sp = bridge.pubs[("n1", "position")]
    session = bridge.session
    recv_bus = can.Bus(interface="virtual", channel=f"{cfg.can.channel}-recv")
    unpack = SGH10_TPDO.unpack_from
    values: dict[int, Any] = {}
    loop = asyncio.get_running_loop()
    stages: dict[str, list[float]] = {}

    def add(name: str, us: float) -> None:
        stages.setdefault(name, []).append(us)

    def bare(i: int) -> None:
        m = frames[i]
        values[m.arbitration_id] = unpack(m.data)

    def from_thread(fn: Callable[[], float]) -> float:
        out: list[float] = []
        t = threading.Thread(target=lambda: out.append(fn()))
        t.start()
        t.join()
        return out[0]

    noop = lambda: None  # noqa: E731
    noop1 = lambda _arg: None  # noqa: E731
    handler(frames[0])  # a value in the image to render
    sv = node.signals["position"]
    quality = node.quality(sv)
    payload = json.dumps(value_payload(sp.sig, sv, quality, sp.scaling))
    same_text = value_json(sp.sig, sv, quality, sp.scaling) == payload
    try:
        for _rep in range(reps):
            for m in frames:
                recv_bus.queue.put(m)
            add(
                "python-can virtual `recv` of a queued frame",
                per_call_us(lambda i: recv_bus.recv(0)),
            )
            add("bare: `struct.unpack_from` into a dict", per_call_us(bare))
            add("codec `decode`", per_call_us(lambda i: codec.decode(frames[i].data)))
            listeners = list(gw.image.value_listeners)
            gw.image.value_listeners.clear()
            try:
                no_pub = per_call_us(lambda i: handler(frames[i]))
            finally:
                gw.image.value_listeners.extend(listeners)
            add("TPDO handler: decode + process image, no listener", no_pub)
            full = per_call_us(lambda i: handler(frames[i]))
            add("TPDO handler with the Zenoh bridge (2 publications)", full)
            add("  of which the Zenoh bridge", full - no_pub)
            add("  value payload dict + `json.dumps`, per signal",
                per_call_us(lambda i: json.dumps(value_payload(sp.sig, sv, quality, sp.scaling))))  # fmt: skip
            add("  the same sample by `payloads.value_json` (one f-string template), per signal",
                per_call_us(lambda i: value_json(sp.sig, sv, quality, sp.scaling)))  # fmt: skip
            add("  zenoh `put` with `timestamp=session.new_timestamp()`, per signal",
                per_call_us(lambda i: sp.pub.put(payload, timestamp=session.new_timestamp())))  # fmt: skip
            add(
                "  zenoh `put` without timestamp, per signal",
                per_call_us(lambda i: sp.pub.put(payload)),
            )
            add("control frame to the event loop: `call_soon_threadsafe`",
                from_thread(lambda: per_call_us(lambda i: loop.call_soon_threadsafe(noop), 5000)))  # fmt: skip
            await asyncio.sleep(0.05)  # let the loop run the callbacks
            post: Any = gw.master._post
            add("  coalesced hop (`Master._post`), frames arriving while the loop is busy",
                from_thread(lambda post=post: per_call_us(lambda i: post(noop1, i), 5000)))  # fmt: skip
            await asyncio.sleep(0.05)
    finally:
        recv_bus.shutdown()
        await gw.stop()
        inj.close()
    sec.notes.append(
        "`payloads.value_json` gives the same text as the JSON encoder for this sample: "
        + ("yes" if same_text else "NO")
        + f" (`{payload}`)."
    )
    s = Summary.of
    base = stages["bare: `struct.unpack_from` into a dict"]
    for name, vals in stages.items():
        if name.startswith(("codec", "TPDO handler: decode")):
            sec.rows.append(Row(name, s(vals), "bare unpack into dict", s(base),
                                s(paired_ratios(vals, base)), digits=2))  # fmt: skip
        else:
            sec.rows.append(Row(name, s(vals), digits=2))
    return sec
