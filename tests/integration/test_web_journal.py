"""The web console's journal (``canopen_gateway.web.journal_log``) over real HTTP on a running gateway:
its entries survive a restart, are filtered by node and kind, the console's own writes are in
the audit with the client's address, a range exports as CSV, bad parameters get a 400 with
words, and a gateway without a journal says so (409)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from canopen_gateway.app import Gateway
from tests.helpers import free_port, gateway_of, make_config, node_operational, wait_until
from tests.integration.test_web_http import TOKEN, http, post
from tests.integration.test_zenoh_history import raise_and_clear

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


def config(journal: Path | None) -> Any:
    extra = {} if journal is None else {"journal": {"path": str(journal)}}
    return make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        health={"port": free_port()},
        web={"writes": True, "token": TOKEN},
        modbus={"enabled": False},
        **extra,
    )


async def started(cfg: Any) -> tuple[Gateway, str]:
    gw = gateway_of(cfg)
    await gw.start()
    await wait_until(lambda: node_operational(gw, "wire"), 8, "wire operational")
    return gw, f"http://127.0.0.1:{gw.health.port}"


async def entries(base: str, query: str) -> list[dict[str, Any]]:
    code, _, body = await http(f"{base}/api/journal?{query}", token=TOKEN)
    assert code == 200, body
    return json.loads(body)["entries"]


async def test_the_journal_survives_a_restart_is_filtered_and_exports_csv(tmp_path) -> None:
    cfg = config(tmp_path / "journal")
    gw, base = await started(cfg)
    try:
        raise_and_clear(gw, 2)
        code, doc = await post(base, "nmt", {"node": "wire", "command": "preop"})
        assert code == 200, doc
        await wait_until(lambda: gw.journal.counts.written >= 6, 5, "entries written")
    finally:
        await gw.stop()

    gw, base = await started(cfg)  # a new gateway process would read the same file
    try:
        emcy = await entries(base, "kind=emcy&node=wire&from=now(-1h)")
        assert [e["text"] for e in emcy] == [
            "wire: EMCY 0xFF05 Position value error",
            "wire: EMCY 0x0000 Cause of the error removed",
        ] * 2
        assert [e["seq"] for e in emcy] == [1, 2, 3, 4]
        audit = await entries(base, "kind=audit")
        assert len(audit) == 1 and audit[0]["text"].startswith("web 127.0.0.1 token: nmt wire nmt")
        assert audit[0]["text"].endswith(": done")
        everything = await entries(base, "")
        assert {e["kind"] for e in everything} == {"state", "emcy", "audit"}
        stamps = [e["ts"] for e in everything]
        assert stamps == sorted(stamps)

        code, headers, body = await http(f"{base}/api/journal.csv?kind=emcy&from=now(-1h)&to=now()", token=TOKEN)
        assert code == 200 and headers["Content-Type"].startswith("text/csv")
        assert "attachment" in headers["Content-Disposition"]
        assert headers["Transfer-Encoding"] == "chunked"  # streamed, whatever its length
        rows = list(csv.DictReader(io.StringIO(body.decode())))
        assert [int(r["seq"]) for r in rows] == [1, 2, 3, 4]
        assert json.loads(rows[0]["payload"])["code"] == "0xFF05"
        code, headers, body = await http(f"{base}/api/journal.json?kind=emcy&from=now(-30m)", token=TOKEN)
        assert code == 200 and headers["Transfer-Encoding"] == "chunked"
        exported = json.loads(body)
        assert [e["seq"] for e in exported] == [1, 2, 3, 4] and exported[0]["payload"]["code"] == "0xFF05"

        code, _, body = await http(f"{base}/healthz")
        status = json.loads(body)["journal"]
        assert status["written"] >= 1 and status["dropped"] == 0 and status["error"] is None
        code, _, body = await http(f"{base}/metrics")
        assert b'canopen_gateway_journal_entries_total{outcome="written"}' in body

        for query, words in (
            ("kind=warning", "kind: warning is not one of state, emcy, audit"),
            ("node=ghost", "no node named 'ghost'"),
            ("from=yesterday", "is not a time"),
            ("to=[now(-1h)..]", "is not a time"),
        ):
            code, _, body = await http(f"{base}/api/journal?{query}", token=TOKEN)
            message = json.loads(body)["message"]
            assert code == 400 and words in message, body
            assert "[" not in message.split("allowed", 1)[-1]  # from=/to= take one instant
    finally:
        await gw.stop()


async def test_without_a_journal_the_console_says_so(tmp_path) -> None:
    gw, base = await started(config(None))
    try:
        code, _, body = await http(f"{base}/api/journal", token=TOKEN)
        assert code == 409 and "journal.path" in json.loads(body)["message"]
        code, _, page = await http(f"{base}/events")
        assert code == 200 and b'id="journal"' in page
    finally:
        await gw.stop()
