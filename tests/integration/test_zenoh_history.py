"""No event lost across an outage: events and values go out through zenoh-ext advanced
publishers, so an AdvancedSubscriber (history + recovery) gets what it missed while the router
was down, in order, and a late joiner gets the cached events and the last value of every
signal. Every payload keeps its own ``seq`` for plain subscribers. (The timed 10 s / 100 events
measurement is bench/zenoh_outage.py; here every wait is on an event, bounded.)"""

from __future__ import annotations

import asyncio
import json
import queue
from typing import Any

import zenoh
import zenoh.ext

from canopen_gateway.app import Gateway
from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.zenoh_client import open_router, session_config

P = "canopen/test"
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


class AdvancedClient:
    """A client session with one AdvancedSubscriber (the recipe of docs/zenoh.md)."""

    def __init__(self, endpoint: str, key: str) -> None:
        self.session = zenoh.open(session_config("client", connect=[endpoint]))
        self.samples: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.sub = zenoh.ext.declare_advanced_subscriber(
            self.session,
            key,
            lambda s: self.samples.put((str(s.key_expr), json.loads(s.payload.to_bytes()))),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
            recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
            subscriber_detection=True,
        )

    async def take(self, n: int, timeout_s: float = 15.0) -> list[tuple[str, Any]]:
        got: list[tuple[str, Any]] = []

        def more() -> bool:
            while True:
                try:
                    got.append(self.samples.get_nowait())
                except queue.Empty:
                    return len(got) >= n

        await wait_until(more, timeout_s, f"{n} samples")
        return got

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def raise_and_clear(gw: Gateway, rounds: int) -> None:
    assert gw.sim is not None
    sim = gw.sim.nodes["wire"]

    def burst(now: float) -> None:
        for _ in range(rounds):
            sim.raise_emcy(0xFF05, 0x80, now=now)  # SGH10 manual 4.5.1: manufacturer error
            sim.clear_emcy(0xFF05, now=now)

    gw.sim.runner.call(burst)


async def test_emcy_events_raised_while_the_router_is_down_arrive_in_order_afterwards() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    cfg = make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        zenoh={"listen": [], "connect": [endpoint]},
    )
    gw = gateway_of(cfg)
    await gw.start()
    sub = AdvancedClient(endpoint, f"{P}/wire/emcy")
    late: AdvancedClient | None = None
    try:
        assert gw.zenoh is not None
        await wait_until(lambda: gw.image.nodes["wire"].usable(), 8, "wire usable")
        raise_and_clear(gw, 2)
        before = [b for _, b in await sub.take(4)]
        assert [b["seq"] for b in before] == [1, 2, 3, 4]

        router.close()
        sent0 = gw.zenoh.events_sent
        raise_and_clear(gw, 10)  # 20 events while nobody can receive them
        await wait_until(lambda: gw.zenoh.events_sent >= sent0 + 20, 5, "20 events put")
        router = open_router(endpoint)

        after = [b for _, b in await sub.take(20)]
        assert [b["seq"] for b in after] == list(range(5, 25))
        assert [b["code"] for b in after] == ["0xFF05", "0x0000"] * 10

        # a subscriber that joins now gets the cached events (up to zenoh.history.events)
        late = AdvancedClient(endpoint, f"{P}/wire/emcy")
        history = [b for _, b in await late.take(24)]
        assert [b["seq"] for b in history] == list(range(1, 25))
    finally:
        sub.close()
        if late is not None:
            late.close()
        await gw.stop()
        router.close()


async def test_a_late_subscriber_gets_the_last_value_of_every_signal_and_the_state() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    cfg = make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        zenoh={"listen": [], "connect": [endpoint]},
    )
    gw = gateway_of(cfg)
    await gw.start()
    late: AdvancedClient | None = None
    try:
        assert gw.zenoh is not None
        await wait_until(lambda: gw.image.nodes["wire"].usable(), 8, "wire usable")
        await wait_until(
            lambda: all(sp.policy.last_quality is not None for sp in gw.zenoh.pubs.values()),
            5,
            "every value published once",
        )
        pubs = list(gw.zenoh.pubs.values())
        # a held value is published once; a subscriber that comes later still gets it
        late = AdvancedClient(endpoint, f"{P}/wire/**")
        want = {sp.key for sp in pubs} | {f"{P}/wire/state"}

        def seen(got: list[tuple[str, Any]]) -> set[str]:
            return {k for k, _ in got}

        got: list[tuple[str, Any]] = []

        def complete() -> bool:
            while True:
                try:
                    got.append(late.samples.get_nowait())
                except queue.Empty:
                    return want <= seen(got)

        await wait_until(complete, 10, f"history of {sorted(want)}")
        states = [b for k, b in got if k.endswith("/state")]
        assert states and all(isinstance(b["seq"], int) for b in states)
        assert states[-1]["nmt_state"] == "operational"
        for k, b in got:
            if "/value/" in k:
                assert b["quality"] == "good" and isinstance(b["seq"], int)
    finally:
        if late is not None:
            late.close()
        await gw.stop()
        router.close()


async def test_without_heartbeats_the_gateway_starts_and_the_cache_still_serves() -> None:
    """``history.heartbeat_ms: 0`` turns the heartbeats off: the advanced publishers then order
    their samples by timestamp, which zenoh allows only with the session's timestamping on."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    cfg = make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        zenoh={"listen": [], "connect": [endpoint], "history": {"heartbeat_ms": 0}},
    )
    gw = gateway_of(cfg)
    await gw.start()
    late: AdvancedClient | None = None
    try:
        assert gw.zenoh is not None and gw.zenoh.up
        position = gw.zenoh.pubs[("wire", "position")]
        await wait_until(lambda: position.policy.last_quality is not None, 8, "position published")
        late = AdvancedClient(endpoint, f"{P}/wire/value/position")
        key, body = (await late.take(1))[0]
        assert key == position.key and body["value"] is not None
    finally:
        if late is not None:
            late.close()
        await gw.stop()
        router.close()


async def test_a_subscriber_that_starts_after_a_node_was_unplugged_gets_the_current_picture() -> (
    None
):
    """The two ways docs/zenoh.md gives: ``get <prefix>/<node>/state`` answers the node as it is
    now (lost), and an AdvancedSubscriber with history gets the cached state samples, the last
    of which says the node is lost; no change of the node is needed for either."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    cfg = make_config(
        [WIRE], simulate={"nodes": "all"}, zenoh={"listen": [], "connect": [endpoint]}
    )
    gw = gateway_of(cfg)
    await gw.start()
    late: AdvancedClient | None = None
    try:
        assert gw.sim is not None
        await wait_until(lambda: gw.image.nodes["wire"].usable(), 8, "wire usable")
        gw.sim.runner.call(lambda now: gw.sim.nodes["wire"].silence())  # unplugged
        await wait_until(lambda: not gw.image.nodes["wire"].health.alive, 8, "wire lost")

        late = AdvancedClient(endpoint, f"{P}/wire/state")
        states: list[Any] = []

        def lost_seen() -> bool:
            while True:
                try:
                    states.append(late.samples.get_nowait()[1])
                except queue.Empty:
                    return bool(states) and states[-1]["alive"] is False

        await wait_until(lost_seen, 10, "the cached state saying lost")

        # off the event loop: the gateway answers queries there
        session = late.session
        replies = await asyncio.to_thread(lambda: list(session.get(f"{P}/wire/state", timeout=5.0)))
        (now,) = [json.loads(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
        assert now["alive"] is False and now["node"] == "wire"
    finally:
        if late is not None:
            late.close()
        await gw.stop()
        router.close()
