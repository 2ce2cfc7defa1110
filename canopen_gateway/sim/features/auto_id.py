"""Feature ``auto_id``: node id assignment by SDO and key press (AP05 manual 5.6.2).

The master writes the new node id to 5F0Ah:02 of the node with the factory id 125 (7Dh):
``67Dh: 2F 0A 5F 02 <id> ..`` (Table 32). Every such device shows "New ID"; the one whose key is
pressed answers the SDO on 5FDh, stores the id (5F0Ah:01, EEPROM) and runs its initialisation
again: boot-up with the new id. An illegal id (not 1..127) aborts with 06090030h and nothing
changes. The simulator presses the key at once (``key_press: auto``, the default) or waits for
``press_key(now)`` (``key_press: manual``, via the node's feature options). The boot-up follows
the SDO answer on the next tick.

On any other node id 5F0Ah:02 is an ordinary parameter.

Parameters (profile ``features: auto_id:``): object, node_id_object, factory_node_id,
reply_cob_id; option key_press.

Imports: python-can (Message), canopen_gateway.canopen.objref, canopen_gateway.sim.features, canopen_gateway.sim.objects.
"""

from __future__ import annotations

import struct
from typing import Any

import can

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register
from canopen_gateway.sim.objects import ABORT_RANGE

FACTORY_NODE_ID = 0x7D  # AP05 manual 5.1 / 5.6.2
STOPPED = 0x04


@register
class AutoId(SimFeature):
    feature = "auto_id"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.obj = ObjRef.parse(params.get("object", "0x5F0A:02"))
        self.node_id_obj = ObjRef.parse(params.get("node_id_object", "0x5F0A:01"))
        self.factory_node_id = int(params.get("factory_node_id", FACTORY_NODE_ID))
        self.reply_cob_id = int(params.get("reply_cob_id", 0x580 + self.factory_node_id))
        self.key_press = str(params.get("key_press", "auto"))
        self.requested_id: int | None = None  # "New ID" shown, waiting for the key
        self._reboot = False

    def on_boot(self, now: float) -> None:
        self.requested_id = None
        self._reboot = False

    def frame_cob_ids(self) -> tuple[int, ...]:
        return (0x600 + self.node.node_id,)  # SDO request of the current node id

    def on_frame(self, msg: can.Message, now: float) -> bool:
        node = self.node
        if node.node_id != self.factory_node_id or node.nmt_state == STOPPED:
            return False
        if msg.arbitration_id != 0x600 + node.node_id or msg.is_remote_frame:
            return False
        data = bytes(msg.data).ljust(8, b"\0")
        if data[0] & 0xE2 != 0x22:  # only an expedited initiate download
            return False
        index, sub = struct.unpack_from("<HB", data, 1)
        if ObjRef(index, sub) != self.obj:
            return False
        new_id = data[4]
        if not 1 <= new_id <= 127:
            node.send(self.reply_cob_id, struct.pack("<BHBI", 0x80, index, sub, ABORT_RANGE))
            return True
        self.requested_id = new_id
        if self.key_press == "auto":
            self.press_key(now)
        return True

    def press_key(self, now: float) -> None:
        """The operator presses the key on this device: adopt the requested id."""
        new_id = self.requested_id
        if new_id is None:
            return
        node = self.node
        node.send(self.reply_cob_id, struct.pack("<BHBI", 0x60, self.obj.index, self.obj.sub, 0))
        for obj in (self.obj, self.node_id_obj):
            if node.values.has(*obj):
                node.set(*obj, new_id)
                node.store.values[(obj.index, obj.sub)] = new_id
        node.store.node_id = new_id
        node.adopt_node_id_at_reset(new_id)
        self.requested_id = None
        self._reboot = True

    def tick(self, now: float) -> None:
        if self._reboot:
            self._reboot = False
            self.node.reset_communication(now)
