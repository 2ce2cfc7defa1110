"""A real Zenoh session for integration tests, the way a cloud client would use one: subscribe
to keys into queues, watch liveliness tokens, send queries. Every blocking zenoh call runs in a
worker thread so the gateway's event loop (same process) keeps running; every wait is bounded.
Also a router-mode session that serves as the Zenoh router (there is no zenohd here)."""

from __future__ import annotations

import asyncio
import json
import queue
import time
from dataclasses import dataclass
from typing import Any

import zenoh

WAIT_S = 5.0


def session_config(
    mode: str, connect: list[str] | None = None, listen: list[str] | None = None
) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    if mode != "client":
        conf.insert_json5("listen/endpoints", json.dumps(listen or []))
    conf.insert_json5("connect/endpoints", json.dumps(connect or []))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def open_router(endpoint: str) -> zenoh.Session:
    """A router-mode session listening on ``endpoint`` (tcp/127.0.0.1:<port>)."""
    return zenoh.open(session_config("router", listen=[endpoint]))


@dataclass
class Sample:
    key: str
    body: Any  # parsed JSON, or bytes for non-JSON payloads
    timestamp: Any
    kind: str


@dataclass
class Reply:
    ok: bool
    key: str | None
    body: Any


def _body(payload: bytes) -> Any:
    try:
        return json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError):
        return payload


class ZClient:
    """A Zenoh session on loopback (peer or client mode) with queue-backed subscriptions."""

    def __init__(self, connect: list[str], mode: str = "peer"):
        self.session = zenoh.open(session_config(mode, connect=connect))
        self._subs: list[Any] = []

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except zenoh.ZError:
                pass
        self.session.close()

    def subscribe(self, key: str) -> queue.Queue[Sample]:
        q: queue.Queue[Sample] = queue.Queue()

        def on_sample(s: zenoh.Sample) -> None:
            q.put(Sample(str(s.key_expr), _body(s.payload.to_bytes()), s.timestamp, str(s.kind)))

        self._subs.append(self.session.declare_subscriber(key, on_sample))
        return q

    def watch_liveliness(self, key: str) -> queue.Queue[Sample]:
        """PUT when a token appears, DELETE when it goes (with the tokens present now)."""
        q: queue.Queue[Sample] = queue.Queue()

        def on_sample(s: zenoh.Sample) -> None:
            q.put(
                Sample(
                    str(s.key_expr),
                    None,
                    s.timestamp,
                    "PUT" if s.kind == zenoh.SampleKind.PUT else "DELETE",
                )
            )

        self._subs.append(
            self.session.liveliness().declare_subscriber(key, on_sample, history=True)
        )
        return q

    async def get(
        self, selector: str, payload: str | bytes | None = None, timeout_s: float = WAIT_S
    ) -> list[Reply]:
        def run() -> list[Reply]:
            out = []
            for r in self.session.get(selector, payload=payload, timeout=timeout_s):
                if r.ok is not None:
                    out.append(Reply(True, str(r.ok.key_expr), _body(r.ok.payload.to_bytes())))
                else:
                    out.append(Reply(False, None, _body(r.err.payload.to_bytes())))
            return out

        return await asyncio.to_thread(run)

    async def get_one(
        self, selector: str, payload: str | bytes | None = None, timeout_s: float = WAIT_S
    ) -> Reply:
        replies = await self.get(selector, payload, timeout_s)
        assert len(replies) == 1, f"{selector}: expected one reply, got {replies}"
        return replies[0]

    async def alive_tokens(self, key: str, timeout_s: float = 2.0) -> set[str]:
        def run() -> set[str]:
            return {
                str(r.ok.key_expr)
                for r in self.session.liveliness().get(key, timeout=timeout_s)
                if r.ok
            }

        return await asyncio.to_thread(run)


async def next_sample(
    q: queue.Queue[Sample], timeout_s: float = WAIT_S, what: str = "a sample"
) -> Sample:
    """The next sample of a queue, waited for in a worker thread (bounded)."""
    try:
        return await asyncio.to_thread(q.get, True, timeout_s)
    except queue.Empty:
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}") from None


async def sample_where(
    q: queue.Queue[Sample], cond: Any, timeout_s: float = WAIT_S, what: str = "a sample"
) -> Sample:
    """The first sample satisfying ``cond`` (others are consumed), bounded."""
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        try:
            s = await asyncio.to_thread(q.get, True, min(left, 0.2))
        except queue.Empty:
            continue
        if cond(s):
            return s


def drain(q: queue.Queue[Sample]) -> list[Sample]:
    out = []
    while True:
        try:
            out.append(q.get_nowait())
        except queue.Empty:
            return out
