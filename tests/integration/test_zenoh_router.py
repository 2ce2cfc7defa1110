"""The Zenoh bridge through a router: the gateway (peer or client mode) and a cloud client (client
mode) both connect to a router-mode session on tcp/127.0.0.1. The router may be missing at
start and may restart: the gateway never needs a restart."""

from __future__ import annotations

import queue
import time
from typing import Any

from canopen_gateway.zenoh_bridge.session import CONNECT_WAIT_S
from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient, drain, open_router, sample_where

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
RAMP = {"wire": {"kind": "ramp", "speed": 2000}}
P = "canopen/test"
WIRE_TOKENS = {f"{P}/alive/_gateway", f"{P}/alive/wire"}


def through_router(router_endpoint: str, mode: str = "peer") -> Any:
    return make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": RAMP},
        zenoh={"mode": mode, "listen": [], "connect": [router_endpoint], "writes": True},
    )


async def good_position(z: ZClient, what: str) -> Any:
    q = z.subscribe(f"{P}/wire/value/position")
    return await sample_where(q, lambda s: s.body["quality"] == "good", 8, what)


async def wait_tokens(z: ZClient, expected: set[str], timeout_s: float = 8.0) -> None:
    deadline = time.monotonic() + timeout_s
    last: set[str] = set()
    while time.monotonic() < deadline:
        last = await z.alive_tokens(f"{P}/alive/**", timeout_s=1.0)
        if expected <= last:
            return
    raise AssertionError(f"liveliness tokens {sorted(expected)} not seen; last seen {sorted(last)}")


async def test_values_tokens_and_queries_flow_through_a_router() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    gw = gateway_of(through_router(endpoint))
    await gw.start()
    z = ZClient([endpoint], mode="client")
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        sample = await good_position(z, "a position through the router")
        assert sample.body["unit"] == "mm" and sample.timestamp is not None
        await wait_tokens(z, WIRE_TOKENS)
        r = await z.get_one(f"{P}/wire/sdo/1008/00")
        assert r.ok and r.body["value"] == "SGH10"
        err = await z.get_one(f"{P}/wire/sdo/1000/00", payload="1")
        assert not err.ok and err.body["code"] == "0x06010002"
    finally:
        z.close()
        await gw.stop()
        router.close()


async def test_a_peer_gateway_starts_without_a_router_and_connects_when_it_appears() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    gw = gateway_of(through_router(endpoint))
    assert gw.zenoh is not None
    bridge = gw.zenoh
    clock = [0.0]  # the bridge's clock: until it is up, each reading is 0.5 s later

    def ticking() -> float:
        if not bridge.up:
            clock[0] += 0.5
        return clock[0]

    gw.zenoh.clock = ticking
    await gw.start()  # nothing listens on the router endpoint yet
    # open waited for a router only its bounded time (on its own clock), then went on
    assert CONNECT_WAIT_S <= clock[0] <= CONNECT_WAIT_S + 1.0
    assert gw.zenoh.up
    router = open_router(endpoint)
    z = ZClient([endpoint], mode="client")
    try:
        await good_position(z, "a position once the router is up")
        await wait_tokens(z, WIRE_TOKENS)
    finally:
        z.close()
        await gw.stop()
        router.close()


async def test_after_a_router_restart_data_flows_again_and_tokens_return() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    gw = gateway_of(through_router(endpoint))
    await gw.start()
    z = ZClient([endpoint], mode="client")
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        q = z.subscribe(f"{P}/wire/value/position")
        before = await sample_where(q, lambda s: s.body["quality"] == "good", 8, "before")
        await wait_tokens(z, WIRE_TOKENS)

        router.close()
        router = open_router(endpoint)  # same endpoint, a new router: no state kept
        drain(q)

        # the same subscription of the same client session gets data again
        after = await sample_where(
            q, lambda s: s.body["seq"] > before.body["seq"], 8, "a position after the restart"
        )
        assert after.body["quality"] == "good"
        await wait_tokens(z, WIRE_TOKENS)
        r = await z.get_one(f"{P}/wire/state")
        assert r.ok and r.body["alive"] is True
    finally:
        z.close()
        await gw.stop()
        router.close()


async def test_a_client_mode_gateway_starts_without_a_router_and_connects_later() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    gw = gateway_of(through_router(endpoint, mode="client"))
    await gw.start()  # client mode: no router -> the bridge keeps trying in the background
    assert gw.zenoh is not None and not gw.zenoh.up
    assert not gw.status()["zenoh"]
    router = open_router(endpoint)
    z = ZClient([endpoint], mode="client")
    try:
        await wait_until(lambda: gw.zenoh.up, 8, "bridge connected to the router")
        await good_position(z, "a position from the client-mode gateway")
        await wait_tokens(z, WIRE_TOKENS)
    finally:
        z.close()
        await gw.stop()
        router.close()


def test_router_mode_session_serves_as_router_for_two_clients() -> None:
    """The test router itself: two client sessions exchange a sample through it."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(endpoint)
    a = ZClient([endpoint], mode="client")
    b = ZClient([endpoint], mode="client")
    try:
        q = b.subscribe("probe/**")
        deadline = time.monotonic() + 5
        got = None
        while got is None and time.monotonic() < deadline:
            a.session.put("probe/x", b"1")
            try:
                got = q.get(timeout=0.1)
            except queue.Empty:  # the route is not there yet
                got = None
        assert got is not None and got.key == "probe/x"
    finally:
        a.close()
        b.close()
        router.close()
