"""The identity objects of each device for Read Device Identification (function 43/14): 1018h,
1008h, 1009h, 100Ah read from the device through the command service once per boot (on the
first identification request after it), and the objects of a unit built from them by
``modbus.identity``.

Imports: commands, errors, image, modbus.identity, northbound.regmap, runtime.ratelimit.
"""

from __future__ import annotations

from typing import Any

import canopen_gateway
from canopen_gateway.commands import CommandService
from canopen_gateway.errors import GatewayError, NotActive, SdoAbort
from canopen_gateway.image import ProcessImage
from canopen_gateway.modbus.identity import IDENTITY_OBJECTS, gateway_objects, node_objects
from canopen_gateway.northbound.regmap import RegisterMap
from canopen_gateway.runtime.ratelimit import RateLimitedLog


class DeviceIdentity:
    """The identification objects of each unit, with what each device said since its boot."""

    def __init__(
        self,
        regmap: RegisterMap,
        image: ProcessImage,
        commands: CommandService,
        gateway_name: str,
        warn: RateLimitedLog,
    ):
        self.regmap = regmap
        self.image = image
        self.commands = commands
        self.gateway_name = gateway_name
        self.warn = warn
        #: per node: (boot epoch, identity objects read from the device in that epoch)
        self._identity: dict[str, tuple[tuple[int, int], dict[str, Any]]] = {}

    async def identification(self, unit: int) -> dict[int, bytes]:
        """The Read Device Identification objects of a unit (``modbus.identity``)."""
        node = self.regmap.units.get(unit)
        if node is None:
            return gateway_objects(canopen_gateway.__version__, self.gateway_name)
        info = self.commands.node(node)
        return node_objects(info.lp, node, info.node_id, await self._identity_read(node))

    async def _identity_read(self, node: str) -> dict[str, Any]:
        """1018h, 1008h, 1009h, 100Ah as read from the device once per boot (on the first
        identification request after it): objects it aborts are left out; a node that is
        not alive or does not answer gives none (the EDS / profile values are served)."""
        image = self.image.nodes[node]
        h = image.health
        epoch = (h.boot_count, h.loss_count)
        hit = self._identity.get(node)
        if hit is not None and hit[0] == epoch:
            return hit[1]
        if not h.alive:
            return {}
        read: dict[str, Any] = {}
        for key, obj in IDENTITY_OBJECTS.items():
            try:
                read[key] = await self.commands.sdo_read(node, obj)
            except SdoAbort:
                continue  # the device does not have it
            except NotActive:
                return read  # a pair's standby reads nothing by SDO: the EDS values, no warning
            except (GatewayError, TimeoutError) as exc:
                self.warn.warning(
                    ("identity", node), "identification of %s: %s not read: %s", node, obj, exc
                )
                return read  # not cached: tried again on the next request
        self._identity[node] = (epoch, read)
        return read
