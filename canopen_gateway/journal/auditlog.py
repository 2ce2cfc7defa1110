"""The audit's place in the journal: the command service's audit sink (``commands.audit``).

Each record goes in under ``<prefix>/audit``, stamped by the journal's clock, after ``shape``
(the app's: raw values made engineering values, the raw ones beside them). The sink answers an
asyncio future that is done once the record is on disk (committed, or dropped by a failing
disk): the command service's caller waits for it, bounded, before its client's reply.

Imports: the standard library, journal.store, journal.clock. Never commands/ (it is handed to
the service as a function), nor an adapter.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable
from typing import Any

from canopen_gateway.journal.clock import ntp64_of_ns
from canopen_gateway.journal.store import Entry, Journal


def _done(fut: asyncio.Future[None]) -> None:
    if not fut.done():
        fut.set_result(None)


class AuditLog:
    """Call it with a record; it journals it and answers when it is on disk (or None)."""

    def __init__(
        self, journal: Journal, key: str, shape: Callable[[dict[str, Any]], dict[str, Any]] = dict
    ) -> None:
        self.journal = journal
        self.key = key
        self.shape = shape

    def __call__(self, record: dict[str, Any]) -> asyncio.Future[None] | None:
        rec = self.shape(record)
        j = self.journal
        data = json.dumps(rec, default=str).encode()
        node = rec.get("node") if isinstance(rec.get("node"), str) else None
        ticket = j.append(Entry(ntp64_of_ns(j.hlc.stamp()), "audit", self.key, node, None, data))
        if not ticket:
            return None
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return None
        fut: asyncio.Future[None] = loop.create_future()

        def on_disk() -> None:  # the writer's thread
            with contextlib.suppress(RuntimeError):  # the loop is closed: nobody waits
                loop.call_soon_threadsafe(_done, fut)

        j.when_done(ticket, on_disk)
        return fut
