"""Who asked for a write or command that reaches the command service.

Who: each adapter says it once per request with ``acting_as`` (a context variable, so the
command service's signatures do not change and each asyncio task has its own): ``modbus
<client address>[ tls role <role>]``, ``zenoh <source id>``, ``web <client address>``,
``ascii <client address>``, ``unknown`` when nobody said. The command service names it in the
log lines of writes that change supervision, and of their refusals.

Imports: the standard library only. Never an adapter.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

WHO: ContextVar[str] = ContextVar("who", default="unknown")


@contextmanager
def acting_as(who: str) -> Iterator[None]:
    """Writes made inside are done as asked by ``who``."""
    token = WHO.set(who)
    try:
        yield
    finally:
        WHO.reset(token)
