"""Feature ``node_id_object``: node id and bit rate set by object, store and reset.

BEI POSI+ manual 002 ch. 5, 2100h "Transmission Rate" and 2101h "Node Number" (POSI+ SF
appendix: 6100h / 6101h, with the old "C5" objects 3000h / 3001h as aliases): "After setting the
baud rate or the node number, the parameters must be saved in the EEPROM with StoreParameters
(1010h) and the new values are set valid after the device is reset (NMT reset node) or power
cycled". And 1011h: after "load" and a reset, "the transmission rate and the node number are
the default values".

As a table of (event -> effect):

- SDO write of the node id / bit rate object -> value stored in the object only; the node keeps
  its node id and bit rate (a read returns the new value)
- 1010h "save"                               -> the object values go to the persistent store
  (``PersistentStore.node_id`` / ``bitrate_index``)
- NMT reset node (81h) or power cycle        -> the stored node id becomes the node id: boot-up,
  SDO, EMCY, TPDO COB-IDs follow ($NODEID defaults); the stored bit rate becomes
  ``bitrate_kbps``
- NMT reset communication (82h)              -> no change of node id (the manual names reset
  node and power cycle only)
- 1011h "load"                               -> the store forgets both; after the next reset the
  EDS defaults apply (node 1, 20 kbit/s on the POSI+)

The node id object always reads the node id in effect after a reset, unless a new value was
written since. A simulator has no physical bit rate: the effective one is ``bitrate_kbps``.

Imports: python-can (Message), canopen_gateway.canopen.cia301, canopen_gateway.sim.features, canopen_gateway.sim.objects, canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from typing import Any

import can

from canopen_gateway.canopen.cia301 import NmtCommand
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register
from canopen_gateway.sim.objects import ABORT_RANGE

SIGNATURE_SAVE = 0x65766173  # manual 002 1010h: "save", bytes 73 61 76 65
SIGNATURE_LOAD = 0x64616F6C  # manual 002 1011h: "load", bytes 6C 6F 61 64


def _refs(v: Any) -> list[ObjRef]:
    return [ObjRef.parse(x) for x in (v or [])]


@register
class NodeIdObject(SimFeature):
    feature = "node_id_object"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.node_id_obj = ObjRef.parse(params.get("node_id", "0x2101:00"))
        self.node_id_aliases = _refs(params.get("node_id_aliases"))
        self.bitrate_obj = ObjRef.parse(params.get("bitrate", "0x2100:00"))
        self.bitrate_aliases = _refs(params.get("bitrate_aliases"))
        self.bitrate_table = {int(k): int(v) for k, v in (params.get("bitrate_kbps") or {}).items()}
        self.store_obj = ObjRef.parse(params.get("store", "0x1010:01"))
        self.store_signature = int(params.get("store_signature", SIGNATURE_SAVE))
        self.restore_obj = ObjRef.parse(params.get("restore", "0x1011:01"))
        self.restore_signature = int(params.get("restore_signature", SIGNATURE_LOAD))
        lo, hi = params.get("node_id_range", (1, 127))
        self.node_id_range = (int(lo), int(hi))
        self.bitrate_code: int | None = None  # in effect since the last reset

    @property
    def bitrate_kbps(self) -> int | None:
        """The bit rate in effect (None if the profile gives no table for the code)."""
        return None if self.bitrate_code is None else self.bitrate_table.get(self.bitrate_code)

    def _has(self, obj: ObjRef) -> bool:
        return self.node.values.has(*obj)

    # -- hooks ---------------------------------------------------------------------------------
    def before_sdo_write(self, obj: ObjRef, value: Any, now: float) -> int | None:
        if obj == self.node_id_obj or obj in self.node_id_aliases:
            lo, hi = self.node_id_range
            if not lo <= int(value) <= hi:
                return ABORT_RANGE
        return None

    def on_boot(self, now: float) -> None:
        store = self.node.store
        if self.node.last_reset in ("power", "node"):
            code = store.bitrate_index
            if code is None and self._has(self.bitrate_obj):
                code = int(self.node.default_of(*self.bitrate_obj))
            self.bitrate_code = code
        # the object shows the node id in effect when nothing else was stored
        if self._has(self.node_id_obj) and not self._stored(self.node_id_obj):
            self._set_all(self.node_id_obj, self.node_id_aliases, self.node.node_id)
        if self._has(self.bitrate_obj) and self.bitrate_code is not None:
            if not self._stored(self.bitrate_obj):
                self._set_all(self.bitrate_obj, self.bitrate_aliases, self.bitrate_code)

    def frame_cob_ids(self) -> tuple[int, ...]:
        return (0x000,)  # NMT

    def on_frame(self, msg: can.Message, now: float) -> bool:
        """NMT reset node: the stored node id is adopted by the core's reset."""
        if msg.arbitration_id != 0 or msg.is_remote_frame or len(msg.data) < 2:
            return False
        cs, target = msg.data[0], msg.data[1]
        if cs == NmtCommand.RESET_NODE and target in (0, self.node.node_id):
            stored = self.node.store.node_id
            if stored is not None and stored != self.node.node_id:
                self.node.adopt_node_id_at_reset(stored)
        return False

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        if obj == self.node_id_obj or obj in self.node_id_aliases:
            self._set_all(self.node_id_obj, self.node_id_aliases, value)
        elif obj in self.bitrate_aliases or obj == self.bitrate_obj:
            self._set_all(self.bitrate_obj, self.bitrate_aliases, value)
        elif obj == self.store_obj and int(value) == self.store_signature:
            self._remember()
        elif obj == self.restore_obj and int(value) == self.restore_signature:
            self.node.store.node_id = None
            self.node.store.bitrate_index = None
            if self._has(self.node_id_obj):
                self.node.store.node_id = int(self.node.default_of(*self.node_id_obj))

    # -- helpers -------------------------------------------------------------------------------
    def _stored(self, obj: ObjRef) -> bool:
        return (obj.index, obj.sub) in self.node.store.values

    def _set_all(self, main: ObjRef, aliases: list[ObjRef], value: Any) -> None:
        for o in [main, *aliases]:
            if self._has(o) and self.node.get(*o) != value:
                self.node.set(*o, value)

    def _remember(self) -> None:
        """1010h "save" just stored every parameter: keep node id and bit rate for the reset."""
        store = self.node.store
        if self._has(self.node_id_obj):
            store.node_id = int(self.node.get(*self.node_id_obj))
            store.values[(self.node_id_obj.index, self.node_id_obj.sub)] = store.node_id
        if self._has(self.bitrate_obj):
            store.bitrate_index = int(self.node.get(*self.bitrate_obj))
            store.values[(self.bitrate_obj.index, self.bitrate_obj.sub)] = store.bitrate_index
