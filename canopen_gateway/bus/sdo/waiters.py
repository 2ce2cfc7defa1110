"""The SDO transfers a client awaits: one future per (node, token), settled by the node's
``SdoDone`` with the typed error a client gets (``SdoAbort``, ``SdoTimeout``).

Owned by the master, used on the event loop only.

Imports: bus.events (SdoDone), errors, canopen.objref, asyncio.
"""

from __future__ import annotations

import asyncio

from canopen_gateway.bus.events import SdoDone
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.errors import GatewayError, SdoAbort, SdoTimeout


class SdoWaiters:
    """Futures of the SDO transfers clients await, by (node name, token)."""

    def __init__(self) -> None:
        self._waiting: dict[tuple[str, int], tuple[asyncio.Future[bytes], ObjRef]] = {}

    def add(self, loop: asyncio.AbstractEventLoop, node: str, token: int, obj: ObjRef) -> asyncio.Future[bytes]:
        fut: asyncio.Future[bytes] = loop.create_future()
        self._waiting[(node, token)] = (fut, obj)
        return fut

    def done(self, node: str, done: SdoDone) -> None:
        """The node finished transfer ``done.token``: its future gets the bytes or the error."""
        entry = self._waiting.pop((node, done.token), None)
        if entry is None:
            return
        fut, obj = entry
        if fut.done():
            return
        if done.data is not None:
            fut.set_result(done.data)
        elif done.by_server and done.abort_code is not None:
            fut.set_exception(SdoAbort(done.abort_code, node=node, obj=str(obj)))
        elif done.timed_out:
            fut.set_exception(SdoTimeout(node, str(obj), "no SDO answer"))
        else:
            fut.set_exception(
                SdoTimeout(node, str(obj), f"transfer ended (0x{done.abort_code or 0:08X})")
            )

    def fail_all(self, error: GatewayError) -> None:
        """Every awaited transfer ends with ``error`` (the gateway stops, or stands by)."""
        for fut, _obj in self._waiting.values():
            if not fut.done():
                fut.set_exception(error)
        self._waiting.clear()
