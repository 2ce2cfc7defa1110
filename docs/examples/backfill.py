"""Every event of a key once and in order, across router outages and gateway restarts: a gap
in ``seq`` is filled from the gateway's journal with a ``_time`` query (docs/zenoh.md, "No
event lost across outages"). ``seq`` never goes back on a key of a gateway with a journal
(restarts, trims, a damaged file: the journal keeps the highest it gave), and the journal's
times never go back either, so "after the last seq and time I saw" is always the rest.
Run: python backfill.py tcp/127.0.0.1:7447 canopen/line1/wire/emcy
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from typing import Any

import zenoh


def rfc3339(ts: zenoh.Timestamp) -> str:
    """A Zenoh timestamp as RFC 3339 to the nanosecond (``_time`` takes it as it is)."""
    return ts.get_time_as_ntp64().to_string_rfc3339_lossy()


def journal(session: zenoh.Session, key: str, since: str) -> Iterator[dict[str, Any]]:
    """Every entry of ``key`` from ``since`` on (RFC 3339; "": the oldest), in order; an answer
    cut at the gateway's time limit is asked again from where it stopped."""
    selector = f"{key}?_time=[{since}..]"
    while selector:
        replies, selector = session.get(selector, timeout=30.0), ""
        for reply in replies:
            if reply.ok is not None:
                yield json.loads(reply.ok.payload.to_bytes())
                continue
            err = json.loads(reply.err.payload.to_bytes())
            if err.get("error") != "cut":
                raise RuntimeError(err.get("message"))
            selector = f"{key}?_time=]{err['resume']}..]"  # the rest, after the last one sent


def backfilled(
    session: zenoh.Session, key: str, last_seq: int = 0, last_time: str = ""
) -> Iterator[tuple[int, dict[str, Any]]]:
    """(seq, payload) of every sample of ``key`` once, in order. ``last_seq`` / ``last_time``
    (RFC 3339): where a previous run stopped (0 / "": from the oldest the journal holds)."""
    sub = session.declare_subscriber(key)  # a FIFO channel: samples are taken here, in order
    for sample in sub:
        body = json.loads(sample.payload.to_bytes())
        seq = body["seq"]
        if seq <= last_seq:
            continue  # delivered already (from the journal)
        if seq > last_seq + 1:  # missed some: the journal has them
            for old in journal(session, key, last_time):
                if last_seq < old["seq"] < seq:
                    last_seq = old["seq"]
                    yield last_seq, old
        last_seq, last_time = seq, rfc3339(sample.timestamp)
        yield seq, body


if __name__ == "__main__":
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    with zenoh.open(conf) as s:
        for n, payload in backfilled(s, sys.argv[2]):
            print(n, payload)
