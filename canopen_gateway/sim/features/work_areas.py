"""Feature ``work_areas``: DS-406 work areas 6400h-6402h (SGH10 manual 4.7.2.32-4.7.2.34).

For each work area n (1, 2) with low limit 6401h:n and high limit 6402h:n, the area state
6400h:n is computed from the position value (the profile's position object):

  bit 2  position < low limit         (4.7.2.32)
  bit 1  position > high limit
  bit 0  position outside the area (bit 1 or bit 2)

An area whose two limits are both 0 (the factory values) is inactive: state 0. The alarm word
6503h bit 11+n follows bit 0 (4.7.2.38: bit 12 area 1, bit 13 area 2). On entering a violation
the EMCY of the area is sent once (manual Table 9: FF15h area 1, FF16h area 2); on leaving it
EMCY 0000h (4.5.1), and 1001h bit 0 stays set while any error persists.

Parameters (profile ``features: work_areas:``): state, low_limit, high_limit (lists of objects),
state_bits {out_of_range, above_high_limit, below_low_limit}, alarms, alarm_bits, emcy (codes).

Imports: canopen_gateway.canopen.objref, canopen_gateway.sim.features.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.sim.features import SimFeature, register

_EVAL_PERIOD_S = 0.005  # how often tick() re-evaluates the areas between TPDOs / SDO reads


def _refs(v: Any, default: list[str]) -> list[ObjRef]:
    return [ObjRef.parse(x) for x in (v or default)]


@register
class WorkAreas(SimFeature):
    feature = "work_areas"

    def __init__(self, node: Any, params: dict[str, Any]) -> None:
        super().__init__(node, params)
        self.state_objs = _refs(params.get("state"), ["0x6400:01", "0x6400:02"])
        self.low_objs = _refs(params.get("low_limit"), ["0x6401:01", "0x6401:02"])
        self.high_objs = _refs(params.get("high_limit"), ["0x6402:01", "0x6402:02"])
        bits = params.get("state_bits") or {}
        self.bit_out = int(bits.get("out_of_range", 0))
        self.bit_high = int(bits.get("above_high_limit", 1))
        self.bit_low = int(bits.get("below_low_limit", 2))
        self.alarm_obj = ObjRef.parse(params.get("alarms", "0x6503:00"))
        self.alarm_bits = [int(b) for b in params.get("alarm_bits", [12, 13])]
        self.emcy_codes = [int(c) for c in params.get("emcy", [0xFF15, 0xFF16])]
        self.violated = [False] * len(self.state_objs)
        self._next_eval_s = 0.0

    def on_boot(self, now: float) -> None:
        self.violated = [False] * len(self.state_objs)

    def tick(self, now: float) -> None:
        if now >= self._next_eval_s:
            self._next_eval_s = now + _EVAL_PERIOD_S
            self.node.update_process(now)

    def update_process(self, now: float) -> None:
        pos_obj = self.node.hints.position
        if pos_obj is None:
            return
        position = int(self.node.get(*pos_obj, 0))
        alarms = (
            int(self.node.get(*self.alarm_obj, 0)) if self.node.values.has(*self.alarm_obj) else 0
        )
        for n, state_obj in enumerate(self.state_objs):
            low = int(self.node.get(*self.low_objs[n], 0))
            high = int(self.node.get(*self.high_objs[n], 0))
            state = 0
            if low != 0 or high != 0:  # both 0: area not configured
                if position > high:
                    state |= 1 << self.bit_high
                if position < low:
                    state |= 1 << self.bit_low
                if state:
                    state |= 1 << self.bit_out
            self.node.set(*state_obj, state)
            outside = bool(state)
            if n < len(self.alarm_bits):
                bit = 1 << self.alarm_bits[n]
                alarms = alarms | bit if outside else alarms & ~bit
            if outside != self.violated[n]:
                self.violated[n] = outside
                if n < len(self.emcy_codes):
                    if outside:
                        self.node.raise_emcy(self.emcy_codes[n], 0, now=now)
                    else:
                        self.node.clear_emcy(self.emcy_codes[n], now=now)
        if self.node.values.has(*self.alarm_obj):
            self.node.set(*self.alarm_obj, alarms)
