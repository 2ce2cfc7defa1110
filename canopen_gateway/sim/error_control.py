"""The simulated device's error control: heartbeat producer and node/life guarding answers.

``ErrorControl(host)`` belongs to one ``SimNode`` and keeps the state of its error control
(SGH10 manual 000/003 section numbers), including whether it is stopped (a fault: no heartbeat,
no guarding answers); it sees its node as ``ErrorControlHost`` (a Protocol):

- heartbeat producer 1017h (4.5.3): ``[NMT state]`` on 0x700+id every period, in any state
  after boot-up; a producer that fell behind (a long pause) sends one, not a burst;
- node guarding (4.5.2): an RTR on 0x700+id is answered with toggle bit 7 (0 first) | state,
  unless the node produces heartbeats (DS-301 7.2.8.3) and the sim hint
  ``guarding_with_heartbeat`` is not set;
- life guarding (4.5.2): once the first RTR came, no RTR within 100Ch x 100Dh ms raises EMCY
  8130h (if the profile lists it); the next RTR clears it.

Sans-I/O as its node: it sends through ``host.send`` and reads no clock.

Imports: canopen_gateway.canopen.cia301 (COB_NMT_EC), canopen_gateway.canopen.states (NmtState); sim.emcy, sim.hints and
sim.objects for types only. Nothing of bus/, modbus/,
zenoh_bridge/.
"""

from __future__ import annotations

from collections.abc import Collection
from typing import TYPE_CHECKING, Protocol

from canopen_gateway.canopen.cia301 import COB_NMT_EC
from canopen_gateway.canopen.states import NmtState

if TYPE_CHECKING:
    from canopen_gateway.sim.emcy import EmcyProducer
    from canopen_gateway.sim.hints import SimHints
    from canopen_gateway.sim.objects import ObjectValues

# Due times are sums of float periods (0.2 + 0.1 > 0.3): a timer is due within this margin.
_EPS_S = 1e-9


class ErrorControlHost(Protocol):
    """What the error control uses of its node."""

    values: ObjectValues
    hints: SimHints
    emcy: EmcyProducer
    node_id: int
    nmt_state: NmtState

    def send(self, cob_id: int, data: bytes = b"", *, rtr: bool = False, dlc: int = 0) -> None: ...
    def raise_emcy(self, code: int, register: int = 0, mfr: bytes = b"", now: float | None = None) -> None: ...
    def clear_emcy(self, code: int, now: float | None = None) -> None: ...


class ErrorControl:
    """Heartbeat producer and guarding answers of one simulated node."""

    def __init__(self, node: ErrorControlHost, *, emcy_codes: Collection[int]) -> None:
        self.node = node
        self.emcy_codes = emcy_codes  # the EMCY codes the device's manual lists
        self.off = False  # heartbeat and guarding answers stopped (a fault)
        self.hb_next_s: float | None = None
        self.guard_toggle = 0
        self.guard_last_rtr_s: float | None = None
        self.life_guarding_lost = False

    def reset(self) -> None:
        """Initialisation: the toggle starts at 0, life guarding waits for the first RTR."""
        self.guard_toggle = 0
        self.guard_last_rtr_s = None
        self.life_guarding_lost = False

    def schedule_heartbeat(self, now: float) -> None:
        period_ms = int(self.node.values.get(0x1017, 0, 0))
        self.hb_next_s = now + period_ms / 1000 if period_ms > 0 else None

    def catch_up(self, now: float) -> None:
        """Back on the bus: a heartbeat that fell due meanwhile is rescheduled from ``now``."""
        if self.hb_next_s is not None and self.hb_next_s < now:
            self.schedule_heartbeat(now)

    def stop(self) -> None:
        """Stop the heartbeat and the answers to node guarding (a fault)."""
        self.off = True

    def resume(self, now: float) -> None:
        """Error control on again: the next heartbeat now."""
        self.off = False
        if self.hb_next_s is not None:
            self.hb_next_s = now

    def tick(self, now: float) -> None:
        self._tick_heartbeat(now)
        self._tick_life_guarding(now)

    def _tick_heartbeat(self, now: float) -> None:
        """Heartbeat producer 1017h (SGH10 manual 4.5.3): [state] every period, any state."""
        node = self.node
        if self.hb_next_s is None or now + _EPS_S < self.hb_next_s or self.off:
            return
        period_s = int(node.values.get(0x1017, 0, 0)) / 1000
        node.send(COB_NMT_EC + node.node_id, bytes([int(node.nmt_state)]))
        if period_s <= 0:
            self.hb_next_s = None
            return
        self.hb_next_s += period_s
        if self.hb_next_s <= now:  # fell behind (e.g. a long pause): no burst
            self.hb_next_s = now + period_s

    def on_guarding_rtr(self, now: float) -> None:
        """Node guarding (SGH10 manual 4.5.2): toggle bit 7 (0 first) | NMT state."""
        node = self.node
        if int(node.values.get(0x1017, 0, 0)) and not node.hints.guarding_with_heartbeat:
            return  # DS-301 7.2.8.3: a node uses heartbeat or guarding, not both
        if self.off:
            return
        node.send(COB_NMT_EC + node.node_id, bytes([(self.guard_toggle << 7) | node.nmt_state]))
        self.guard_toggle ^= 1
        self.guard_last_rtr_s = now
        if self.life_guarding_lost:
            self.life_guarding_lost = False
            if 0x8130 in node.emcy.active:
                node.clear_emcy(0x8130, now)

    def _tick_life_guarding(self, now: float) -> None:
        """Life guarding: no RTR within 100Ch x 100Dh ms after the first one (4.5.2)."""
        if self.guard_last_rtr_s is None or self.life_guarding_lost:
            return
        node = self.node
        guard_ms = int(node.values.get(0x100C, 0, 0))
        factor = int(node.values.get(0x100D, 0, 0))
        if guard_ms == 0 or factor == 0:
            return
        if now - self.guard_last_rtr_s > guard_ms * factor / 1000:
            self.life_guarding_lost = True
            if 0x8130 in self.emcy_codes:  # only if the manual lists it
                node.raise_emcy(0x8130, 0x10, now=now)  # DS-301: life guard error, bit 4
