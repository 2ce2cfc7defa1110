"""Every event of a key once and in order, across router outages and gateway restarts: a gap
in ``seq`` is filled from the gateway's journal with a ``_time`` query (docs/zenoh.md, "No
event lost across outages"). Run: python backfill.py tcp/127.0.0.1:7447 canopen/line1/wire/emcy
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from typing import Any

import zenoh


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
            for reply in session.get(f"{key}?_time=[{last_time}..]", timeout=30.0):
                if reply.ok is None:
                    raise RuntimeError(reply.err.payload.to_string())
                old = json.loads(reply.ok.payload.to_bytes())
                if last_seq < old["seq"] < seq:
                    last_seq = old["seq"]
                    yield last_seq, old
        last_seq, last_time = seq, sample.timestamp.get_time().isoformat()
        yield seq, body


if __name__ == "__main__":
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
    with zenoh.open(conf) as s:
        for n, payload in backfilled(s, sys.argv[2]):
            print(n, payload)
