"""Feature ``heartbeat_consumer``: the device watches another node's heartbeat (DS-301 1016h).

BEI POSI+ manual 002 ch. 4: 1016h:01 "Consumer Heartbeat Time 1", bits 0-15 the time in ms,
bits 16-23 the node id of the producer (normally the master); error code 8130h "Life Guard error
or Heartbeat error" in 1003h:01; error register 1001h bit 4 "communication error".

What the node does, as a table of (event -> reaction):

- entry written with time 0 or node id 0     -> entry off, a pending error is cleared
- heartbeat 0x700+id received (any state byte) -> entry armed (DS-301: monitoring starts
  with the first heartbeat), last-seen time = now
- armed, now - last seen > time              -> lost: EMCY 8130h, 1001h bits 0 and 4,
  1003h:00 = 1, 1003h:01 = 8130h (EMCY frame only in PRE-OPERATIONAL/OPERATIONAL)
- lost, heartbeat received again             -> EMCY 0000h (error reset), 1001h cleared
- reset node / communication / power-on      -> every entry disarmed, error forgotten

The manual names no NMT reaction (the device has no 1029h), so the NMT state does not change.
The EMCY code and error register bits come from the feature parameters.

Imports: python-can (Message), canopen_gateway.sim.features, canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import can

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

COB_HEARTBEAT_BASE = 0x700  # DS-301 NMT error control (boot-up / heartbeat)
DEFAULT_EMCY_CODE = 0x8130  # manual 002 ch. 4, 1003h:01: life guard error or heartbeat error
DEFAULT_REGISTER_BITS = (0, 4)  # manual 002 ch. 4, 1001h: bit 0 generic, bit 4 communication
_EPSILON_S = 1e-9  # float clocks: a heartbeat exactly one period late is still in time


@dataclass
class _Entry:
    producer_id: int = 0
    time_ms: int = 0
    last_seen_s: float | None = None  # None: not armed (no heartbeat seen yet)
    lost: bool = False


def _bit_range(v: Any, default: tuple[int, int]) -> tuple[int, int]:
    lo, hi = v if v is not None else default
    return int(lo), int(hi)


@register
class HeartbeatConsumer(SimFeature):
    feature = "heartbeat_consumer"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        first = ObjRef.parse(params.get("object", "0x1016:01"))
        self.index = first.index
        self.time_bits = _bit_range(params.get("time_bits"), (0, 15))
        self.node_id_bits = _bit_range(params.get("node_id_bits"), (16, 23))
        self.emcy_code = int(params.get("emcy_code", DEFAULT_EMCY_CODE))
        bits = params.get("error_register_bits", DEFAULT_REGISTER_BITS)
        self.register_bits = sum(1 << int(b) for b in bits)
        self.entries: dict[int, _Entry] = {}

    # -- configuration -------------------------------------------------------------------------
    @staticmethod
    def _field(value: int, bits: tuple[int, int]) -> int:
        lo, hi = bits
        return (value >> lo) & ((1 << (hi - lo + 1)) - 1)

    def _load(self, sub: int) -> _Entry:
        raw = int(self.node.get(self.index, sub, 0))
        return _Entry(self._field(raw, self.node_id_bits), self._field(raw, self.time_bits))

    def _subs(self) -> list[int]:
        return [s for (i, s) in self.node.values.keys() if i == self.index and s > 0]

    def _reload_all(self) -> None:
        self.entries = {s: self._load(s) for s in self._subs()}

    @property
    def lost(self) -> bool:
        return any(e.lost for e in self.entries.values())

    def _update_error(self, now: float) -> None:
        active = self.emcy_code in self.node.emcy.active
        if self.lost and not active:
            self.node.raise_emcy(self.emcy_code, self.register_bits, now=now)
        elif not self.lost and active:
            self.node.clear_emcy(self.emcy_code, now=now)

    # -- hooks ---------------------------------------------------------------------------------
    def on_boot(self, now: float) -> None:
        self._reload_all()
        if self.emcy_code in self.node.emcy.active:
            self.node.clear_emcy(self.emcy_code, now=now)  # no frame while initialising

    def after_sdo_write(self, obj: ObjRef, value: Any, now: float) -> None:
        if obj.index != self.index or obj.sub == 0:
            return
        self.entries[obj.sub] = self._load(obj.sub)
        self._update_error(now)

    def frame_cob_ids(self) -> range:
        return range(COB_HEARTBEAT_BASE + 1, COB_HEARTBEAT_BASE + 128)  # any producer 1..127

    def on_frame(self, msg: can.Message, now: float) -> bool:
        if msg.is_remote_frame or msg.is_extended_id or len(msg.data) < 1:
            return False
        producer = msg.arbitration_id - COB_HEARTBEAT_BASE
        if not 1 <= producer <= 127 or producer == self.node.node_id:
            return False
        changed = False
        for e in self.entries.values():
            if e.producer_id == producer and e.time_ms > 0:
                e.last_seen_s = now
                if e.lost:
                    e.lost = False
                    changed = True
        if changed:
            self._update_error(now)
        return False

    def tick(self, now: float) -> None:
        changed = False
        for e in self.entries.values():
            if e.lost or e.last_seen_s is None or e.time_ms <= 0 or e.producer_id == 0:
                continue
            if now - e.last_seen_s > e.time_ms / 1000 + _EPSILON_S:
                e.lost = True
                changed = True
        if changed:
            self._update_error(now)
