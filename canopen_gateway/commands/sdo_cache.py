"""The SDO value cache of the command service: SDO-backed values read north are served from it
while younger than ``master.sdo_cache_ms`` (default 1000 ms) and read in the node's current
boot epoch; concurrent reads of one value share one upload; a write through the gateway
updates it; a boot-up or loss of the node (a new epoch) empties it for that node.

Imports: bus.network (the SDO transfers, routed to the node's network), bus.node.parts (the nodes), device.values (value
codecs), profiles.schema.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from canopen_gateway.bus.network import Networks
from canopen_gateway.bus.node.parts import NodeParts
from canopen_gateway.device.values import decode_value, encode_value
from canopen_gateway.profiles.schema import Signal


def _epoch(p: NodeParts) -> tuple[int, int]:
    """The node's boot epoch: a cached value read in another one is not served."""
    h = p.image.health
    return h.boot_count, h.loss_count


class SdoValueCache:
    """Values of SDO-backed signals by (node, signal), with the time and epoch of their read."""

    def __init__(self, networks: Networks, max_age_s: float):
        self.master = networks
        self.max_age_s = max_age_s
        #: node -> its network's ``master.sdo_cache_ms`` in seconds (else ``max_age_s``)
        self.ages: dict[str, float] = {}
        self._values: dict[tuple[str, str], tuple[Any, float, tuple[int, int]]] = {}
        self._reading: dict[tuple[str, str], asyncio.Future[Any]] = {}

    async def read(self, p: NodeParts, sig: Signal, cached: bool = False) -> Any:
        """The device's value of ``sig`` by SDO upload; ``cached``: from the cache while young
        enough, or shared with an upload already in flight."""
        key = (p.name, sig.name)
        now = time.monotonic()
        if cached:
            hit = self._values.get(key)
            age_s = self.ages.get(p.name, self.max_age_s)
            if hit is not None and now - hit[1] <= age_s and hit[2] == _epoch(p):
                return hit[0]
            pending = self._reading.get(key)
            if pending is not None:
                return await asyncio.shield(pending)
        fut: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._reading[key] = fut
        try:
            epoch = _epoch(p)
            data = await self.master.sdo(p.name, sig.object, None)
            value = decode_value(bytes(data), sig.type_name)
            self._values[key] = (value, time.monotonic(), epoch)
            fut.set_result(value)
            return value
        except BaseException as exc:
            fut.set_exception(exc)
            fut.exception()  # retrieved: no "never retrieved" warning when nobody shares it
            raise
        finally:
            if self._reading.get(key) is fut:
                del self._reading[key]

    async def write(self, p: NodeParts, sig: Signal, value: Any) -> None:
        """SDO download of ``sig``; the value written is then the cached one."""
        await self.master.sdo(p.name, sig.object, encode_value(value, sig.type_name))
        self._values[(p.name, sig.name)] = (value, time.monotonic(), _epoch(p))

    def forget(self, node: str, name: str) -> None:
        """Drop a cached value (its object was written by a raw SDO write)."""
        self._values.pop((node, name), None)
