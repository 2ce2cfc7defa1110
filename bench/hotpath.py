"""Where the time of one TPDO goes: the hot path taken apart, stage by stage, in microseconds.

Each stage is called directly in a loop on prebuilt frames (one thread, no contention, 20,000
calls per repetition) inside a started gateway with one SGH10 node: python-can ``recv`` of a
queued frame, the codec's ``decode``, the TPDO handler without listeners (decode + process
image), the Zenoh bridge's share for one frame with ``publish: every`` (2 signals), its parts
(payload + JSON, ``put`` with and without a zenoh timestamp), and the hop of a control frame
(heartbeat, EMCY) to the event loop by ``call_soon_threadsafe``. The bare listener's
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
from gateway.zenoh_bridge.payloads import QUALITY_TEXT, value_payload

N_CALLS = 20_000


def template_json(sig: Any, sv: Any, quality: Any, sc: Any, unit_json: str) -> str:
    """A proposal measured here, not used by the gateway: a value sample of a plain integer
    signal (no bits, no value texts) rendered with one f-string instead of a dict and the JSON
    encoder; the text is the same as ``json.dumps(value_payload(...))``."""
    raw = sv.value
    value = raw if sc.identity else round(raw * sc.scale + sc.offset, 9)
    q = QUALITY_TEXT[quality]
    return (
        f'{{"value": {value!r}, "unit": {unit_json}, "ts": {sv.timestamp!r}, '
        f'"quality": "{q}", "seq": {sv.seq}}}'
    )


class CoalescedHop:
    """A proposal measured here, not used by the gateway: control frames handed to the event
    loop through a list, with one ``call_soon_threadsafe`` (one self-pipe write) per batch
    instead of one per frame."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self.loop = loop
        self.lock = threading.Lock()
        self.pending: list[tuple[Callable[[Any], None], Any]] = []
        self.scheduled = False

    def put(self, fn: Callable[[Any], None], arg: Any) -> None:
        with self.lock:
            self.pending.append((fn, arg))
            if self.scheduled:
                return
            self.scheduled = True
        self.loop.call_soon_threadsafe(self.drain)

    def drain(self) -> None:
        with self.lock:
            items, self.pending = self.pending, []
            self.scheduled = False
        for fn, arg in items:
            fn(arg)


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
    unit_json = json.dumps(sp.scaling.unit)
    same_text = template_json(sp.sig, sv, quality, sp.scaling, unit_json) == payload
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
            add("  proposal: the same sample by one f-string template, per signal",
                per_call_us(lambda i: template_json(sp.sig, sv, quality, sp.scaling, unit_json)))  # fmt: skip
            add("  zenoh `put` with `timestamp=session.new_timestamp()`, per signal",
                per_call_us(lambda i: sp.pub.put(payload, timestamp=session.new_timestamp())))  # fmt: skip
            add(
                "  zenoh `put` without timestamp, per signal",
                per_call_us(lambda i: sp.pub.put(payload)),
            )
            add("control frame to the event loop: `call_soon_threadsafe`",
                from_thread(lambda: per_call_us(lambda i: loop.call_soon_threadsafe(noop), 5000)))  # fmt: skip
            await asyncio.sleep(0.05)  # let the loop run the callbacks
            put = CoalescedHop(loop).put
            add("  proposal: coalesced hop, frames arriving while the loop is busy",
                from_thread(lambda put=put: per_call_us(lambda i: put(noop1, i), 5000)))  # fmt: skip
            await asyncio.sleep(0.05)
    finally:
        recv_bus.shutdown()
        await gw.stop()
        inj.close()
    sec.notes.append(
        "The template proposal gives the same text as the JSON encoder for this sample: "
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
