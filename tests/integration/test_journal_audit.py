"""The audit records every write that may have reached a device, on disk before the client's
answer: a CiA 309-3 ASCII write is audited with the value as a number (the object's type
read from its bytes) and the bytes beside it; a write cut by its client's timeout is audited
``unknown``. And a router's access rule denying queries on ``<prefix>/audit`` holds against a
wildcard history get (``<prefix>/**?_time=[..]`` answers the state, never the audit)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import zenoh

from canopen_gateway.journal import Row
from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.integration.test_ascii_gateway import WIRE, Client
from tests.integration.test_zenoh_auth import USERS, UserClient, session_conf

P = "canopen/test"
COB_SDO_RX_WIRE = 0x601  # CiA 301: SDO client -> server of node 1


def audit_rows(gw: Any) -> list[dict[str, Any]]:
    rows: list[Row] = list(gw.journal.read(kinds=["audit"]))
    return [json.loads(r.payload) for r in rows]


async def test_ascii_writes_are_audited_with_numbers_before_the_answer_even_when_cut(tmp_path: Path) -> None:
    cfg = make_config(
        [WIRE],
        modbus={"enabled": False},
        zenoh={"enabled": False},
        ascii={"port": free_port(), "writes": True},
        journal={"path": str(tmp_path / "journal")},
    )
    gw = gateway_of(cfg)
    await gw.start()
    c = None
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 1 w 0x6200 0 u16 499") == "[1] OK"
        (done,) = audit_rows(gw)  # read as soon as the answer came: it is on disk already
        assert done["who"].startswith("ascii 127.0.0.1:") and done["op"] == "sdo_write"
        assert "6200" in done["what"] and done["value"] == 499 and done["raw"] == "f301"
        assert done["outcome"] == "done"

        sim = gw.sim.nodes["wire"]
        answer = sim.handle
        sim.handle = lambda msg, now: [] if msg.arbitration_id == COB_SDO_RX_WIRE else answer(msg, now)
        assert await c.ask("[2] set sdo_timeout 100") == "[2] OK"
        assert (await c.ask("[3] 1 w 0x6200 0 u16 7")).startswith("[3] ERROR:")  # no answer
        cut = audit_rows(gw)[-1]  # the request went out: the device may have taken it
        assert cut["outcome"] == "unknown" and cut["value"] == 7 and "detail" in cut
    finally:
        if c is not None:
            await c.close()
        await gw.stop()


ACCESS_CONTROL = {
    "enabled": True,
    "default_permission": "allow",
    "rules": [{"id": "no-audit", "messages": ["query"], "flows": ["ingress"],
               "permission": "deny", "key_exprs": [f"{P}/audit"]}],
    "subjects": [{"id": "viewers", "usernames": ["viewer"]}],
    "policies": [{"rules": ["no-audit"], "subjects": ["viewers"]}],
}  # fmt: skip


async def test_a_router_rule_denying_the_audit_holds_against_a_wildcard_history_get(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    users = tmp_path / "users.txt"
    users.write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
    conf = session_conf("router", endpoint)
    conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(users)))
    conf.insert_json5("access_control", json.dumps(ACCESS_CONTROL))
    router = zenoh.open(conf)
    cfg = make_config(
        [WIRE],
        simulate={"nodes": "all"},
        zenoh={"mode": "client", "listen": [], "connect": [endpoint], "writes": True,
               "auth": {"user": "gateway-line1", "password": USERS["gateway-line1"]}},
        journal={"path": str(tmp_path / "journal")},
    )  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    viewer = operator = None
    try:
        await wait_until(lambda: gw.zenoh.up and gw.image.nodes["wire"].usable(), 10, "up")
        operator = UserClient(endpoint, "operator", USERS["operator"])
        assert (await operator.get_one(f"{P}/wire/nmt", payload="start")).ok
        audit = await operator.get(f"{P}/audit?_time=[..]")
        assert [r.body["op"] for r in audit] == ["nmt"]  # the audit, asked for by its name

        viewer = UserClient(endpoint, "viewer", USERS["viewer"])
        everything = await viewer.get(f"{P}/**?_time=[..]")
        keys = {r.key for r in everything}
        assert f"{P}/wire/state" in keys and f"{P}/audit" not in keys
        assert await viewer.get(f"{P}/audit?_time=[..]", timeout_s=1.0) == []  # denied
    finally:
        for client in (viewer, operator):
            if client is not None:
                client.close()
        await gw.stop()
        router.close()
