"""The audit of every write and command that reaches the command service: who asked, what
(node, signal or object, value) and the outcome (``done``, or the error: its kind, the SDO
abort code, the text).

Who: each adapter says it once per request with ``acting_as`` (a context variable, so the
command service's signatures do not change and each asyncio task has its own): ``modbus
<client address>[ tls role <role>]``, ``zenoh <source id>``, ``web <client address>``,
``ascii <client address>``, ``watchdog`` for the safe outputs, ``unknown`` when nobody said.

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

F = TypeVar("F", bound=Callable[..., Any])
Describe = Callable[..., tuple[str, str, Any]]  # the operation's arguments -> node, what, value
AuditSink = Callable[[dict[str, Any]], None]  # takes one record (``record``)


@contextmanager
def acting_as(who: str) -> Iterator[None]:
    """Writes made inside are audited as asked by ``who``."""
    token = WHO.set(who)
    try:
        yield
    finally:
        WHO.reset(token)


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
    return {
        "ts": time.time(),
        "who": WHO.get(),
        "op": op,
        "node": node,
        "what": what,
        "value": _plain(value),
        "outcome": outcome_of(exc),
    }


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
