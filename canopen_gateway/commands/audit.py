"""The audit of every write and command that reaches the command service: who asked, what
(node, signal or object, value; the raw value beside it) and the outcome (``done``, the error:
its kind, the SDO abort code, the text; ``unknown`` when the write may have reached the device
without its answer: cancelled by its client's timeout, an SDO timeout).

Who: each adapter says it once per request with ``acting_as`` (a context variable, so the
command service's signatures do not change and each asyncio task has its own), and only what
it has authenticated or seen itself: ``modbus <client address>[ tls role <role> subject
<certificate subject>]``, ``zenoh`` (a query does not say who sent it: the router's logins and
access control decide who may), ``web <client address>[ token]`` (``token``: the request
carried the operators' token), ``ascii <client address:port>``, ``watchdog`` for the safe
outputs, ``unknown`` when nobody said. What a client says of itself (Zenoh's ``source_info``,
an ``X-Canopen-Client`` header) is never the identity: it is kept as ``hint``, marked as said
by the client.

Writes refused before they reach the service (a write gate: Modbus ``allowed_networks`` or
``read_only``, ``zenoh.writes``, ``ascii.writes``) and wrong web tokens are audited too
(``RefusalAudit``): ``outcome`` ``refused: <why>``, at most one record per client, operation
and reason every ``REFUSAL_PERIOD_S`` (the next one says how many were not recorded), so a
client that hammers a gate cannot push older entries out of a bounded journal.

The service marks its write operations with ``audited`` and hands each record to its ``audit``
sink (the app journals it); with no sink nothing is recorded and nothing is built. The sink
may return an awaitable that ends when the record is on disk: the operation's caller gets its
answer after that (the audit before the client's reply), waiting ``AUDIT_WAIT_S`` at most (a
stalled disk never holds a write's answer longer). A write cancelled while it runs (its
client's timeout) is recorded too, before the cancellation goes on.

Imports: errors. Never an adapter, never the journal (the sink is a function given to it).
"""

from __future__ import annotations

import asyncio
import functools
import time
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, TypeVar, cast

from canopen_gateway.errors import GatewayError, SdoAbort, SdoTimeout

WHO: ContextVar[str] = ContextVar("who", default="unknown")
#: what the client said of itself (never checked): recorded as ``hint``
HINT: ContextVar[str | None] = ContextVar("hint", default=None)
#: refusals of one client, operation and reason are audited at most once per period
REFUSAL_PERIOD_S = 10.0

F = TypeVar("F", bound=Callable[..., Any])
#: the service and the operation's arguments -> (node, what, value) or (node, what, value, raw)
Describe = Callable[..., tuple[Any, ...]]
#: takes one record (``record``); may return an awaitable that ends once it is on disk
AuditSink = Callable[[dict[str, Any]], Awaitable[Any] | None]
#: the longest a write's answer waits for its audit to be on disk
AUDIT_WAIT_S = 0.2
UNKNOWN = "unknown"


@contextmanager
def acting_as(who: str, hint: str | None = None) -> Iterator[None]:
    """Writes made inside are audited as asked by ``who`` (what the adapter authenticated or
    saw itself); ``hint``: what the client said of itself, recorded as such."""
    token, hint_token = WHO.set(who), HINT.set(hint)
    try:
        yield
    finally:
        WHO.reset(token)
        HINT.reset(hint_token)


def outcome_of(exc: BaseException | None) -> tuple[str, str | None]:
    """The outcome and, for ``unknown``, why."""
    if exc is None:
        return "done", None
    if isinstance(exc, asyncio.CancelledError | TimeoutError):
        return UNKNOWN, "cancelled before its answer (the client's timeout): the device may have taken it"
    if isinstance(exc, SdoTimeout):
        return UNKNOWN, f"{exc.kind}: {exc} (the device may have taken it)"
    if isinstance(exc, SdoAbort):
        return f"abort 0x{exc.code:08X}: {exc.text}", None
    if isinstance(exc, GatewayError):
        return f"{exc.kind}: {exc}", None
    return f"error: {type(exc).__name__}: {exc}", None


def plain(value: Any) -> Any:
    """The value as JSON can hold it (bytes as hex text)."""
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if value is None or isinstance(value, (int, float, str, bool)):
        return value
    return str(value)


class Fields(dict[str, Any]):
    """Fields of an audit record that are not the node's (the network of an NMT command to
    ``all`` of one network), given last by a describe; a value or raw that is a dict stays one."""


def record(op: str, what: tuple[Any, ...], exc: BaseException | None) -> dict[str, Any]:
    """``what``: (node, what, value) or (node, what, value, raw), and last, where a field of
    the record is not the node's, a :class:`Fields`."""
    extra: dict[str, Any] = what[-1] if what and isinstance(what[-1], Fields) else {}
    if extra:
        what = what[:-1]
    node, name, value = what[:3]
    outcome, detail = outcome_of(exc)
    rec = {
        "ts": time.time(),
        "who": WHO.get(),
        "op": op,
        "node": node,
        "what": name,
        "value": plain(value),
        "outcome": outcome,
    }
    if len(what) > 3:
        rec["raw"] = plain(what[3])
    rec.update(extra)
    if detail is not None:
        rec["detail"] = detail
    hint = HINT.get()
    if hint is not None:
        rec["hint"] = f"{hint} (said by the client, not verified)"
    return rec


class RefusalAudit:
    """Refused writes and failed logins as audit records, at most one per (who, operation,
    reason) and period; ``sink()`` is read at each refusal (None: not audited). A refused
    write never reached a device: its record is handed over without waiting for the disk."""

    def __init__(
        self,
        sink: Callable[[], AuditSink | None],
        clock: Callable[[], float] = time.monotonic,
        period_s: float = REFUSAL_PERIOD_S,
        max_kinds: int = 4096,
    ) -> None:
        self.sink = sink
        self.clock = clock
        self.period_s = period_s
        self.max_kinds = max_kinds
        self._last: dict[tuple[str, str, str], tuple[float, int]] = {}  # -> (at, not recorded)

    def refused(self, op: str, node: str, what: str, value: Any, why: str) -> None:
        sink = self.sink()
        if sink is None:
            return
        kind, now = (WHO.get(), op, why), self.clock()
        at, skipped = self._last.get(kind, (None, 0))
        if at is not None and now - at < self.period_s:
            self._last[kind] = (at, skipped + 1)
            return
        if len(self._last) >= self.max_kinds:
            self._last.clear()  # a flood of distinct clients: forget, never grow
        self._last[kind] = (now, 0)
        doc = record(op, (node, what, value), None)
        doc["outcome"] = f"refused: {why}"
        if skipped:
            # the skipped came within period_s of the previous record, whenever this one comes
            doc["outcome"] += f" ({skipped} more like it not recorded since the previous record)"
        sink(doc)


async def _on_disk(done: Awaitable[Any] | None) -> None:
    """Wait (``AUDIT_WAIT_S`` at most) for a record to be on disk."""
    if done is None:
        return
    try:
        await asyncio.wait_for(asyncio.shield(done), AUDIT_WAIT_S)
    except TimeoutError:
        pass


def audited(op: str, describe: Describe) -> Callable[[F], F]:
    """Mark an async method of the command service as a write to audit: one record per call,
    its outcome or the exception it raised (a cancellation too), on disk before it returns."""

    def deco(fn: F) -> F:
        @functools.wraps(fn)
        async def run(self: Any, *args: Any, **kw: Any) -> Any:
            sink = self.audit
            if sink is None:
                return await fn(self, *args, **kw)
            try:
                result = await fn(self, *args, **kw)
            except BaseException as exc:
                if isinstance(exc, Exception | asyncio.CancelledError):
                    await _on_disk(sink(record(op, describe(self, *args, **kw), exc)))
                raise
            await _on_disk(sink(record(op, describe(self, *args, **kw), None)))
            return result

        return cast(F, run)

    return deco
