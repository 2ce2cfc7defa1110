"""Store and forward in one process: a gateway with ``journal.path`` commits its state and EMCY
events before it publishes them, answers ``get <key>?_time=[...]`` from the journal (one reply
per sample, in time order, the payload as published with its ``seq`` and the original Zenoh
timestamp), continues every key's ``seq`` after a restart, audits every write (who, what,
outcome) under ``<prefix>/audit``, and answers a bad selector with ``reply_err``."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import zenoh

from canopen_gateway.app import Gateway
from tests.helpers import gateway_of, make_config, wait_until, wait_until_sync
from tests.integration.test_zenoh_history import raise_and_clear
from tests.zenoh_client import ZClient

P = "canopen/test"
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


def config(journal: Path, **zenoh_extra: Any) -> Any:
    return make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "hold"}}},
        zenoh={"writes": True, **zenoh_extra},
        journal={"path": str(journal), "values_ms": 100},
    )


def history(session: zenoh.Session, selector: str) -> list[tuple[str, Any, str]]:
    """(key, body, timestamp) of every reply; an error reply as ("error", body, "")."""
    out = []
    for r in session.get(selector, timeout=10.0):
        if r.ok is not None:
            ts = r.ok.timestamp
            out.append((str(r.ok.key_expr), json.loads(r.ok.payload.to_bytes()), str(ts)))
        else:
            out.append(("error", json.loads(r.err.payload.to_bytes()), ""))
    return out


async def history_of(session: zenoh.Session, selector: str, n: int) -> list[tuple[str, Any, str]]:
    """``history`` once it holds ``n`` replies or more (asked again until then, bounded)."""

    def enough() -> list[tuple[str, Any, str]] | None:
        replies = history(session, selector)
        return replies if len(replies) >= n else None

    return await asyncio.to_thread(wait_until_sync, enough, 10, f"{n} replies to {selector}")


async def started(cfg: Any) -> Gateway:
    gw = gateway_of(cfg)
    await gw.start()
    await wait_until(lambda: gw.image.nodes["wire"].usable(), 8, "wire usable")
    return gw


async def test_events_are_journaled_before_published_and_answered_by_time_range(tmp_path) -> None:
    cfg = config(tmp_path / "journal")
    gw = await started(cfg)
    z = ZClient(cfg.zenoh.listen)
    live = z.subscribe(f"{P}/wire/emcy")
    try:
        assert gw.zenoh is not None and gw.journal is not None
        raise_and_clear(gw, 5)
        await wait_until(lambda: live.qsize() >= 10, 10, "10 EMCY samples")
        got = [live.get_nowait() for _ in range(10)]
        seen = [(s.body["seq"], str(s.timestamp)) for s in got]
        assert [s for s, _ in seen] == list(range(1, 11))

        replies = await asyncio.to_thread(history, z.session, f"{P}/wire/emcy?_time=[now(-5m)..]")
        assert [(b["seq"], ts) for _, b, ts in replies] == seen  # as published, same timestamps
        assert {k for k, _, _ in replies} == {f"{P}/wire/emcy"}
        assert [b["code"] for _, b, _ in replies] == ["0xFF05", "0x0000"] * 5

        # a range that ends before the fifth event: the first four
        fifth = got[4].timestamp.get_time().isoformat()
        before = await asyncio.to_thread(history, z.session, f"{P}/wire/emcy?_time=[..{fifth}[")
        assert [b["seq"] for _, b, _ in before] == [1, 2, 3, 4]

        states = await asyncio.to_thread(history, z.session, f"{P}/wire/state?_time=[..]")
        assert states and [b["seq"] for _, b, _ in states] == list(range(1, len(states) + 1))
        assert states[-1][1]["nmt_state"] == "operational"

        # every key of a wildcard, merged in time order
        both = await asyncio.to_thread(history, z.session, f"{P}/wire/*?_time=[now(-5m)..]")
        stamps = [zenoh_time(ts) for _, _, ts in both]
        assert stamps == sorted(stamps) and len(both) == len(states) + 10

        # without _time a get keeps its meaning: the current state
        now = await z.get_one(f"{P}/wire/state")
        assert now.ok and now.body["nmt_state"] == "operational"
    finally:
        z.close()
        await gw.stop()


def zenoh_time(ts: str) -> int:
    return int(ts.split("/")[0])


async def test_seq_goes_on_after_a_restart_and_values_have_a_history(tmp_path) -> None:
    cfg = config(tmp_path / "journal")
    gw = await started(cfg)
    raise_and_clear(gw, 2)
    assert gw.zenoh is not None
    await wait_until(lambda: gw.zenoh.events_sent >= 4, 5, "4 events put")
    await wait_until(lambda: gw.journal.counts.written >= 6, 5, "values journaled")
    await gw.stop()

    gw = await started(cfg)
    z = ZClient(cfg.zenoh.listen)
    try:
        raise_and_clear(gw, 1)
        replies = await history_of(z.session, f"{P}/wire/emcy?_time=[..]", 6)
        assert [b["seq"] for _, b, _ in replies] == [1, 2, 3, 4, 5, 6]
        states = await asyncio.to_thread(history, z.session, f"{P}/wire/state?_time=[..]")
        seqs = [b["seq"] for _, b, _ in states]
        assert seqs == list(range(1, len(seqs) + 1))  # no restart at 1: a gap would be a loss
        values = await asyncio.to_thread(
            history, z.session, f"{P}/wire/value/position?_time=[now(-1h)..now()]"
        )
        assert values and all("value" in b and "quality" in b for _, b, _ in values)
        vseqs = [b["seq"] for _, b, _ in values]
        assert vseqs == sorted(vseqs) and len(set(vseqs)) == len(vseqs)
    finally:
        z.close()
        await gw.stop()


async def test_writes_are_audited_with_who_what_and_the_outcome(tmp_path) -> None:
    cfg = config(tmp_path / "journal")
    gw = await started(cfg)
    z = ZClient(cfg.zenoh.listen)
    try:
        ok = await z.get_one(f"{P}/wire/nmt", payload="preop")
        assert ok.ok
        bad = await z.get_one(f"{P}/wire/sdo/6000/00", payload="4", timeout_s=10)
        failed = await z.get_one(f"{P}/wire/sdo/1000/00", payload="1")  # read-only: aborted
        assert not failed.ok
        audit = await history_of(z.session, f"{P}/audit?_time=[now(-1m)..]", 3)
        bodies = [b for _, b, _ in audit]
        assert [(b["op"], b["node"], b["what"]) for b in bodies] == [
            ("nmt", "wire", "nmt"),
            ("sdo_write", "wire", "0x6000:00"),
            ("sdo_write", "wire", "0x1000:00"),
        ]
        assert all(b["who"].startswith("zenoh") for b in bodies)
        assert bodies[0]["value"] == "preop" and bodies[0]["outcome"] == "done"
        assert (bodies[1]["outcome"] == "done") == bad.ok  # the audit says what the reply said
        assert bodies[2]["outcome"].startswith("abort 0x0601")  # CiA 301: read-only object
    finally:
        z.close()
        await gw.stop()


async def test_bad_selectors_get_reply_err_naming_what_is_wrong(tmp_path) -> None:
    cfg = config(tmp_path / "journal")
    gw = await started(cfg)
    z = ZClient(cfg.zenoh.listen)
    try:
        for selector, words in (
            (f"{P}/wire/emcy?_time=yesterday", "_time"),
            (f"{P}/wire/emcy?_time=[now(-5 parsecs)..]", "not a duration"),
            (f"{P}/wire/emcy?_time=[now()..now(-1h)]", "start is after the end"),
        ):
            replies = await asyncio.to_thread(history, z.session, selector)
            assert len(replies) == 1 and replies[0][0] == "error", selector
            assert words in replies[0][1]["message"], (selector, replies)
            assert "<duration>" not in replies[0][1]["message"]  # a selector cannot carry it
        # as a Zenoh storage: a key without history answers nothing, and Zenoh's durations work
        for selector in (f"{P}/wire/snapshot?_time=[..]", f"{P}/ghost/emcy?_time=[now(-30)..]"):
            assert await asyncio.to_thread(history, z.session, selector) == []
    finally:
        z.close()
        await gw.stop()


async def test_publish_pdo_keeps_a_value_history_per_signal(tmp_path) -> None:
    """``publish: pdo`` puts one sample per TPDO on ``<node>/tpdo/<n>``; the journal keeps each
    signal's values on its value key all the same (the tpdo key has no history: empty)."""
    cfg = make_config(
        [WIRE],
        simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp"}}},
        zenoh={"publish": "pdo"},
        journal={"path": str(tmp_path / "journal"), "values_ms": 100},
    )
    gw = await started(cfg)
    z = ZClient(cfg.zenoh.listen)
    try:
        values = await history_of(z.session, f"{P}/wire/value/position?_time=[now(-1m)..]", 2)
        assert all(k == f"{P}/wire/value/position" and "value" in b for k, b, _ in values)
        seqs = [b["seq"] for _, b, _ in values]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        assert await asyncio.to_thread(history, z.session, f"{P}/wire/tpdo/1?_time=[..]") == []
    finally:
        z.close()
        await gw.stop()
