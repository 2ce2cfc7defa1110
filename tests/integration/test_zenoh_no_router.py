"""A client-mode gateway whose Zenoh router is away: one plain log line (where it looked, when it
tries again; no Rust source locations), and readiness as documented (docs/deploy.md): a gateway
whose Modbus serves stays ready with ``zenoh: false`` in /healthz; one without Modbus, whose
only northbound side is Zenoh, is not ready. The router's port is closed for real (nothing
listens there)."""

from __future__ import annotations

import json
import logging

import pytest

from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.integration.test_health_http import http_get

DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}


def client_config(**sections: object) -> object:
    router = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    return make_config(
        [DISPLAY],
        zenoh={"mode": "client", "listen": [], "connect": [router]},
        health={"port": free_port()},
        **sections,
    )


async def test_no_router_is_one_plain_line_and_a_modbus_gateway_stays_ready(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG, logger="gateway.zenoh")
    cfg = client_config()
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: gw.image.nodes["display"].usable(), 8, "display usable")
        router = cfg.zenoh.connect[0]
        warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert warnings[0] == (
            f"no Zenoh router at {router}: retrying in 0.5 s, then less often, up to every 5 s "
            "(Modbus and the bus run meanwhile; check the router, the address, zenoh.auth and "
            "zenoh.tls)"
        )
        # a background attempt that failed since says the same in its own words, plainly
        assert all(m.startswith(f"no Zenoh router at {router}") for m in warnings), warnings
        assert not any(".rs:" in m or ".cargo" in m for m in warnings)
        code, _, body = await http_get(f"http://127.0.0.1:{gw.health.port}/healthz")
        doc = json.loads(body)
        assert (code, doc["status"], doc["ready"]) == (200, "ready", True)
        assert doc["zenoh"] is False and doc["modbus"] is True
    finally:
        await gw.stop()


async def test_a_gateway_whose_only_northbound_side_is_zenoh_is_not_ready_without_router() -> None:
    cfg = client_config(modbus={"enabled": False})
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: gw.image.nodes["display"].usable(), 8, "display usable")
        code, _, body = await http_get(f"http://127.0.0.1:{gw.health.port}/healthz")
        doc = json.loads(body)
        assert (code, doc["status"], doc["zenoh"]) == (503, "not-ready", False)
    finally:
        await gw.stop()


async def test_a_peer_whose_connect_endpoint_does_not_answer_says_so_until_it_does(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Peer mode with ``zenoh.connect`` and nothing there (or a refused login: Zenoh does not
    tell them apart): the session opens anyway, so the gateway says it reaches nobody, one
    line, and /healthz says ``zenoh: false``; once the router is there, ``zenoh: true`` again."""
    from tests.zenoh_client import open_router

    caplog.set_level(logging.INFO, logger="gateway.zenoh")
    router_at = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there yet
    cfg = make_config([DISPLAY], zenoh={"mode": "peer", "listen": [], "connect": [router_at]},
                      health={"port": free_port()})  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    router = None
    try:
        await wait_until(lambda: gw.zenoh is not None and gw.zenoh.session is not None, 10, "the session open")
        await wait_until(lambda: gw.status()["zenoh"] is False, 15, "zenoh: false while nobody answers")
        (line,) = [r.getMessage() for r in caplog.records if "none of zenoh.connect answers" in r.getMessage()]
        assert line.startswith(f"Zenoh (peer mode): none of zenoh.connect answers ({router_at})")
        assert "zenoh.auth" in line and gw.status()["ready"]  # Modbus serves: ready, as a client
        router = open_router(router_at)
        await wait_until(lambda: gw.status()["zenoh"] is True, 15, "zenoh: true once the router answers")
        assert any("connected again" in r.getMessage() for r in caplog.records)
    finally:
        await gw.stop()
        if router is not None:
            router.close()
