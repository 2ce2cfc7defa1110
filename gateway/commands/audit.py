"""The audit of every write and command that reaches the command service: who asked, what
(node, signal or object, value) and the outcome (``done``, or the error: its kind, the SDO
abort code, the text).

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
sink (the app journals it); with no sink nothing is recorded and nothing is built.

Imports: errors. Never an adapter, never the journal (the sink is a function given to it).
"""

from __future__ import annotations

import functools
import inspect
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, TypeVar, cast

from gateway.errors import GatewayError, SdoAbort

WHO: ContextVar[str] = ContextVar("who", default="unknown")
#: what the client said of itself (never checked): recorded as ``hint``
HINT: ContextVar[str | None] = ContextVar("hint", default=None)
#: refusals of one client, operation and reason are audited at most once per period
REFUSAL_PERIOD_S = 10.0

F = TypeVar("F", bound=Callable[..., Any])
Describe = Callable[..., tuple[str, str, Any]]  # the operation's arguments -> node, what, value
AuditSink = Callable[[dict[str, Any]], None]  # takes one record (``record``)


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


def outcome_of(exc: BaseException | None) -> str:
    if exc is None:
        return "done"
    if isinstance(exc, SdoAbort):
        return f"abort 0x{exc.code:08X}: {exc.text}"
    if isinstance(exc, GatewayError):
        return f"{exc.kind}: {exc}"
    return f"error: {type(exc).__name__}: {exc}"


def _plain(value: Any) -> Any:
    """The value as JSON can hold it (bytes as hex text)."""
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if value is None or isinstance(value, (int, float, str, bool)):
        return value
    return str(value)


def record(op: str, node: str, what: str, value: Any, exc: BaseException | None) -> dict[str, Any]:
    doc = {
        "ts": time.time(),
        "who": WHO.get(),
        "op": op,
        "node": node,
        "what": what,
        "value": _plain(value),
        "outcome": outcome_of(exc),
    }
    hint = HINT.get()
    if hint is not None:
        doc["hint"] = f"{hint} (said by the client, not verified)"
    return doc


class RefusalAudit:
    """Refused writes and failed logins as audit records, at most one per (who, operation,
    reason) and period; ``sink()`` is read at each refusal (None: not audited)."""

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
        doc = record(op, node, what, value, None)
        doc["outcome"] = f"refused: {why}"
        if skipped:
            doc["outcome"] += f" ({skipped} more like it not recorded in the {self.period_s:g} s before)"
        sink(doc)


@contextmanager
def _auditing(sink: AuditSink, op: str, describe: Describe, args: Any, kw: Any) -> Iterator[None]:
    """One record for the call made inside: its outcome, or the exception it raised."""
    try:
        yield
    except Exception as exc:
        sink(record(op, *describe(*args, **kw), exc))
        raise
    sink(record(op, *describe(*args, **kw), None))


def audited(op: str, describe: Describe) -> Callable[[F], F]:
    """Mark a method of the command service (async or not) as a write to audit."""

    def deco(fn: F) -> F:
        if inspect.iscoroutinefunction(fn):

            @functools.wraps(fn)
            async def run_async(self: Any, *args: Any, **kw: Any) -> Any:
                sink = self.audit
                if sink is None:
                    return await fn(self, *args, **kw)
                with _auditing(sink, op, describe, args, kw):
                    return await fn(self, *args, **kw)

            return cast(F, run_async)

        @functools.wraps(fn)
        def run(self: Any, *args: Any, **kw: Any) -> Any:
            sink = self.audit
            if sink is None:
                return fn(self, *args, **kw)
            with _auditing(sink, op, describe, args, kw):
                return fn(self, *args, **kw)

        return cast(F, run)

    return deco
