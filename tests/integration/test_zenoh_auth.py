"""Who may connect and query, with Zenoh's own mechanisms, through a router: the router (a
router-mode eclipse-zenoh session with the shipped deploy/zenoh/router.json5: logins and
access control) knows three users; the gateway logs in with ``zenoh.auth`` from its config as
its prefix's own login. A wrong password cannot connect, the viewer may read but its writes
never reach the gateway (nothing on the bus), the operator writes; the gateway publishes,
answers and announces itself under its prefix."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import can
import pytest
import zenoh

from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient

P = "canopen/line1"
USERS = {"gateway-line1": "gw-secret", "operator": "op-secret", "viewer": "view-secret"}
ROUTER = Path(__file__).resolve().parents[2] / "deploy" / "zenoh" / "router.json5"


def session_conf(mode: str, endpoint: str, user: str | None = None, password: str | None = None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if mode == "router":
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    else:
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if user is not None:
        conf.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return conf


def secure_router(endpoint: str, tmp: Path) -> zenoh.Session:
    """The shipped router configuration, on a test port with the test's users file."""
    users = tmp / "users.txt"
    users.write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    conf = zenoh.Config.from_file(str(ROUTER))
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users)))
    return zenoh.open(conf)


class UserClient(ZClient):
    def __init__(self, endpoint: str, user: str, password: str) -> None:
        self.session = zenoh.open(session_conf("client", endpoint, user, password))
        self._subs: list[Any] = []


async def test_users_passwords_and_access_control_through_a_router(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = secure_router(endpoint, tmp_path)
    (tmp_path / "gateway.password").write_text("gw-secret\n")
    cfg = make_config(
        [{"name": "display", "node_id": 125, "profile": "ap05"}],
        gateway={"name": "line1"},
        zenoh={
            "mode": "client",
            "listen": [],
            "connect": [endpoint],
            "writes": True,
            "auth": {"user": "gateway-line1", "password_file": str(tmp_path / "gateway.password")},
        },
    )
    gw = gateway_of(cfg)
    await gw.start()
    clients: list[ZClient] = []
    bus = None
    try:
        assert gw.zenoh is not None and gw.zenoh.up  # the gateway logged in
        await wait_until(lambda: gw.image.nodes["display"].usable(), 8, "display usable")

        with pytest.raises(zenoh.ZError):
            zenoh.open(session_conf("client", endpoint, "operator", "wrong"))
        with pytest.raises(zenoh.ZError):
            zenoh.open(session_conf("client", endpoint))  # no credentials at all

        viewer = UserClient(endpoint, "viewer", USERS["viewer"])
        operator = UserClient(endpoint, "operator", USERS["operator"])
        clients += [viewer, operator]
        bus = can.Bus(interface="virtual", channel=cfg.can.channel)

        state = await viewer.get_one(f"{P}/display/state")  # reads stay open to the viewer
        # the gateway's login announces it under its prefix through the closed router
        assert {f"{P}/alive/_gateway", f"{P}/alive/display"} <= await viewer.alive_tokens(f"{P}/alive/**")
        assert state.ok and state.body["node"] == "display"
        denied = await viewer.get(f"{P}/display/set/set_point2", payload="1111", timeout_s=1.0)
        assert denied == []  # the router dropped the query: no reply at all
        assert await viewer.get(f"{P}/display/nmt", payload="stop", timeout_s=1.0) == []

        ok = await operator.get_one(f"{P}/display/set/set_point2", payload="2222")
        assert ok.ok, ok.body
        assert gw.sim is not None
        await wait_until(
            lambda: gw.sim.runner.call(lambda now: gw.sim.nodes["display"].get(0x5F16, 1)) == 2222,
            3,
            "operator's set point in 5F16h:01",
        )
        sent = []
        while (m := bus.recv(0)) is not None:
            sent.append(bytes(m.data))
        assert any((2222).to_bytes(4, "little") in d for d in sent)
        assert not any((1111).to_bytes(4, "little") in d for d in sent)
        assert not any(m == b"\x02\x7d" for m in sent)  # no NMT stop to node 125
    finally:
        if bus is not None:
            bus.shutdown()
        for c in clients:
            c.close()
        await gw.stop()
        router.close()


async def test_the_gateway_cannot_join_a_router_with_a_wrong_password(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = secure_router(endpoint, tmp_path)
    cfg = make_config(
        [{"name": "display", "node_id": 125, "profile": "ap05"}],
        zenoh={
            "mode": "client",
            "listen": [],
            "connect": [endpoint],
            "auth": {"user": "gateway-line1", "password": "not-the-password"},
        },
    )
    gw = gateway_of(cfg)
    await gw.start()  # starts (Modbus and the bus run), Zenoh keeps trying in the background
    try:
        assert gw.zenoh is not None and not gw.zenoh.up
        # Modbus serves: ready for a readiness probe, the cloud side reported down
        assert gw.status()["zenoh"] is False and gw.status()["modbus"] is True
    finally:
        await gw.stop()
        router.close()
