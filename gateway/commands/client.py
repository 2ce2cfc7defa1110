"""Who asked for a command: the client an adapter serves, named in the log lines of writes
that change supervision (and their refusals).

Each adapter runs a client's request inside ``acting_for("Modbus client 10.0.0.7")``; the
command service reads ``current_client()`` where it logs. A context variable, so the name
follows the request through the awaits of its own task and never leaks into another's. A
request made outside any adapter (a test, the gateway itself) says ``unknown client``.

Imports: the standard library only.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

UNKNOWN_CLIENT = "unknown client"

_CLIENT: ContextVar[str] = ContextVar("gateway_client", default=UNKNOWN_CLIENT)


def current_client() -> str:
    """The client of the request being served (``unknown client`` outside an adapter)."""
    return _CLIENT.get()


@contextmanager
def acting_for(client: str) -> Iterator[None]:
    """Serve one request of ``client``: commands inside name it in their log lines."""
    token = _CLIENT.set(client)
    try:
        yield
    finally:
        _CLIENT.reset(token)
