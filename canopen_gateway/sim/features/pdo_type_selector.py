"""Feature ``pdo_type_selector``: an object chooses the TPDO layout (BEI POSI+ manual 002, 2005h).

The selector (profile ``pdo_variants.selector``, 0x2005:00 on the POSI+) holds one 4-bit type per
TPDO: bits 3..0 for PDO1, bits 7..4 for PDO2. Type 0 is the layout of the mapping objects
(1A00h/1A01h: position 6004h, 4 bytes); type 2 is the 8-byte frame position (bytes 0-3), speed
2002h (bytes 4-5), 00h 00h (bytes 6-7). The layouts are taken from the profile's
``pdo_variants``, so the byte order lives in the profile, not here. The mapping objects keep
reading as the manual prints them (1A00h:00 = 1, 1A00h:01 = 60040020h) whatever the type.

Writes of a selector value the manual does not list (anything but 00h, 02h, 20h, 22h on the
POSI+) are refused with SDO abort 06090030h (value range exceeded). With software 1.01
(6507h bytes 2,3 < 0102h) the selector is not storable and returns to 00h at every reset.

Imports: canopen_gateway.sim.features, canopen_gateway.sim.pdo, canopen_gateway.sim.objects, canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from typing import Any

import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register
from canopen_gateway.sim.objects import ABORT_RANGE

TYPE_BITS = 4  # manual 002 5, 2005h: bit 3..0 = PDO1, bit 7..4 = PDO2
SOFTWARE_VERSION = ObjRef(0x6507, 0)  # manual 002 6: bytes 2,3 = software version (0102h = 1.02)


@register
class PdoTypeSelector(SimFeature):
    feature = "pdo_type_selector"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        variants = node.profile.profile.pdo_variants
        if variants is None:
            raise ValueError("feature pdo_type_selector needs pdo_variants in the profile")
        self.selector = ObjRef.parse(params.get("selector", str(variants.selector)))
        self.default_value = int(variants.default)
        allowed = params.get("allowed_values")
        self.allowed = {int(v) for v in (allowed if allowed is not None else variants.variants)}
        self.storable_from = int(params.get("storable_from_software_version", 0))
        # TPDO number -> selector type -> mapping entries in byte order
        self._layouts: dict[int, dict[int, list[pdo.MapEntry]]] = {}
        for value in variants.variants:
            tpdos, _ = node.profile.profile.layout(value)
            for t in tpdos:
                kind = self.type_of(int(value), t.number)
                entries = [pdo.MapEntry(e.object.index, e.object.sub, e.bits) for e in t.mapping]
                self._layouts.setdefault(t.number, {})[kind] = entries

    # -- the layout ----------------------------------------------------------------------------
    @staticmethod
    def type_of(selector_value: int, number: int) -> int:
        """The type of TPDO ``number`` (1-based) in a selector value."""
        return (selector_value >> (TYPE_BITS * (number - 1))) & ((1 << TYPE_BITS) - 1)

    def selector_value(self) -> int:
        return int(self.node.get(*self.selector, self.default_value))

    def tpdo_data(self, number: int, data: bytes, now: float) -> bytes:
        """The frame of TPDO ``number``: the core's ``data`` for type 0, else the variant's."""
        kind = self.type_of(self.selector_value(), number)
        if kind == self.type_of(self.default_value, number):
            return data
        entries = self._layouts.get(number, {}).get(kind)
        if entries is None:
            return data
        return pdo.pack(self.node.values, entries)

    # -- hooks ---------------------------------------------------------------------------------
    def before_sdo_write(self, obj: ObjRef, value: Any, now: float) -> int | None:
        if obj == self.selector and int(value) not in self.allowed:
            return ABORT_RANGE
        return None

    def on_boot(self, now: float) -> None:
        if not self.storable_from:
            return
        version = int(self.node.get(*SOFTWARE_VERSION, 0)) >> 16
        if version < self.storable_from:
            self.node.set(*self.selector, self.default_value)
