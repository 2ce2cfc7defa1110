"""LSS Fast Scan from the console's commissioning API over real HTTP, on the running gateway's
own connection to the bus, against identical simulated SGH10s shipped unconfigured (serial
numbers unknown): lowest LSS address first, each given the next node id and stored, which it
takes at the next NMT reset communication; behind the commissioning rules (the token, one LSS
session at a time, a network by name, 400 with words for a bad body)."""

from __future__ import annotations

import json
from typing import Any

from tests.helpers import free_port, gateway_of, make_config, wait_until
from tests.integration.test_web_http import TOKEN, http

SGH10 = {"vendor": "0x195", "product": "0xFFFFFFFF", "revision": "0xFFFFFFFF"}  # SGH10 manual 4.6
SERIALS = {"enc_a": 0x2300, "enc_b": 0x0F01}


async def fast_scan(base: str, body: dict[str, Any], token: str | None = TOKEN) -> tuple[int, dict[str, Any]]:
    code, _, data = await http(f"{base}/api/commission/lss-fast-scan", body, token=token, method="POST")
    return code, json.loads(data)


async def test_fast_scan_gives_identical_unconfigured_devices_node_ids_lowest_address_first() -> None:
    options = {name: {"features": {"lss_slave": {"unconfigured": True, "serial_number": serial}}}
               for name, serial in SERIALS.items()}  # fmt: skip
    cfg = make_config(
        [{"name": name, "node_id": i, "profile": "sgh10", "configure": False} for i, name in enumerate(SERIALS, 1)],
        health={"port": free_port()}, web={"writes": True, "token": TOKEN},
        modbus={"enabled": False}, zenoh={"enabled": False}, simulate={"options": options},
    )  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    base = f"http://127.0.0.1:{gw.health.port}"
    try:
        assert (await fast_scan(base, SGH10, token=None))[0] == 401
        code, doc = await fast_scan(base, {**SGH10, "count": 2})
        assert code == 400 and "needs node_id" in doc["message"]
        code, doc = await fast_scan(base, {**SGH10, "network": "line9"})
        assert code == 404 and "default" in doc["message"]

        code, doc = await fast_scan(base, {**SGH10, "node_id": 20, "count": 2, "store": True, "wait_ms": 50})
        assert code == 200, doc
        assert doc["found"] == [
            {"address": "0x00000195:0xFFFFFFFF:0xFFFFFFFF:0x00000F01", "node_id": 20, "stored": True},
            {"address": "0x00000195:0xFFFFFFFF:0xFFFFFFFF:0x00002300", "node_id": 21, "stored": True},
        ]
        assert doc["failed"] is None and doc["network"] == "default" and "reset communication" in doc["note"]
        # given node ids, they no longer take part: a second scan finds nobody, in words
        code, doc = await fast_scan(base, {**SGH10, "wait_ms": 20})
        assert code == 504 and "no unconfigured LSS slave answered" in doc["message"]

        # at the next NMT reset communication each device takes its id (LSS inquiry by address)
        code, _, _ = await http(f"{base}/api/commission/nmt", {"node": "all", "command": "reset-comm"},
                                token=TOKEN, method="POST")  # fmt: skip
        assert code == 200
        lower = gw.sim.nodes["enc_b"]
        await wait_until(lambda: lower.node_id == 20, 5, "enc_b took node id 20")
        code, _, data = await http(f"{base}/api/commission/lss-inquire",
                                   {"address": "0x195:0xFFFFFFFF:0xFFFFFFFF:0xF01"}, token=TOKEN, method="POST")  # fmt: skip
        assert code == 200 and json.loads(data)["node_id"] == 20
    finally:
        await gw.stop()
