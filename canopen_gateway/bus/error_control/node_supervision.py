"""A node's supervision (``NodeSupervision``, the node's ``supervision``): heartbeat consumer or
node-guarding master (``bus.error_control.supervision``), with what each NMT command makes the node
expected to report, and what the node's lifecycle says it expects.

Rule: the tables below are the code. Node guarding treats a valid answer with another state
than the expected one as an error (DS-301), so the expectation must follow the node's life: a
node being configured after its boot-up answers PRE-OPERATIONAL, which is right, not a fault.

Imports: bus.error_control.supervision, device.settings, canopen.states. No I/O, no clock. Not the
node's lifecycle: the node tells it the state to expect (``bus.node.lifecycle_actions``,
``GUARD_EXPECTS``).
"""

from __future__ import annotations

from canopen_gateway.bus.error_control.supervision import (
    HeartbeatConsumer,
    InvalidStateByte,
    NodeGuardingMaster,
    NodeLost,
    SendGuardRtr,
    ToggleError,
    WrongState,
)
from canopen_gateway.canopen.states import REPORTED_STATES, NmtState
from canopen_gateway.device.settings import NodeSettings

#: The state a node is meant to be in after an NMT command (None: it reboots, boot-up follows).
NMT_EXPECTS: dict[str, NmtState | None] = {
    "start": NmtState.OPERATIONAL,
    "stop": NmtState.STOPPED,
    "preop": NmtState.PRE_OPERATIONAL,
    "reset": None,
    "reset-comm": None,
}


class NodeSupervision:
    """Heartbeat consumer, node-guarding master, or nothing (``supervision: none``)."""

    def __init__(self, s: NodeSettings, configure: bool = True):
        grace = s.boot_timeout_s if configure else None
        self.hb: HeartbeatConsumer | None = (
            HeartbeatConsumer(s.heartbeat_ms, s.heartbeat_multiple, grace)
            if s.heartbeat_ms > 0 and s.supervision == "heartbeat"
            else None
        )
        self.guard: NodeGuardingMaster | None = (
            NodeGuardingMaster(s.guard_time_ms, s.life_time_factor)
            if s.supervision == "guarding"
            else None
        )
        #: False while the node only listens (lifecycle LISTENING): no guarding RTR, no life
        #: time of ours; the other master's RTRs heard count instead (``on_rtr_heard``)
        self.guarding = True

    @property
    def alive(self) -> bool:
        """Whether supervision counts the node alive (always, without supervision)."""
        sup = self.guard or self.hb
        return sup is None or sup.alive

    def next_deadline(self) -> float | None:
        if self.guard is not None and self.guarding:
            if not self.guard.guarding_started:
                return 0.0  # the first poll activates guarding (its first RTR)
            return self.guard.next_deadline()
        return self.hb.next_deadline() if self.hb is not None else None

    def answer(self, byte: int, now: float) -> tuple[NmtState | None, list[str]]:
        """A heartbeat or guarding answer: the NMT state it validly reports (None: not valid)
        and the problems it shows (toggle, wrong state, undefined byte)."""
        if self.guard is not None:
            outs = self.guard.on_response(byte, now)
        elif self.hb is not None:
            outs = self.hb.on_heartbeat(byte, now)
        else:
            outs = []
        bad = [o for o in outs if isinstance(o, (ToggleError, WrongState, InvalidStateByte))]
        state = byte & 0x7F
        if bad or state not in REPORTED_STATES:
            return None, [str(o) for o in bad] or [f"state byte 0x{byte:02X}"]
        return NmtState(state), []

    def poll(self, now: float) -> tuple[bool, str | None]:
        """(send a guarding RTR now, reason if the node was just lost)."""
        rtr, lost = False, None
        if self.guard is not None and self.guarding:
            for o in self.guard.poll(now):
                if isinstance(o, SendGuardRtr):
                    rtr = True
                elif isinstance(o, NodeLost):
                    lost = o.reason
        if self.hb is not None:
            for o in self.hb.poll(now):
                if isinstance(o, NodeLost):
                    lost = o.reason
        return rtr, lost

    def on_bootup(self, now: float) -> None:
        if self.hb is not None:
            self.hb.on_bootup(now)
        if self.guard is not None:
            self.guard.on_bootup(now)  # the toggle bit starts at 0 again (DS-301)

    def on_found(self, now: float) -> None:
        """Found running by a probe: heartbeat monitoring restarts as after a boot-up."""
        if self.hb is not None and not self.hb.alive:
            self.hb.on_bootup(now)

    @property
    def guard_lost(self) -> bool:
        return self.guard is not None and self.guard.lost

    def on_lifecycle(self, expects: NmtState | None, listening: bool) -> None:
        """The node's lifecycle changed: guarding expects ``expects`` (None: any valid state);
        while the node only ``listening``, no guarding RTR and no life time of ours."""
        self.guarding = not listening
        if self.guard is not None:
            self.guard.expect(expects)

    def on_rtr_heard(self) -> str | None:
        """Another master's guarding RTR to the node while it only listens: the reason when
        the node is lost by it (more RTRs than the life time factor unanswered), else None."""
        if self.guard is None or self.guarding:
            return None
        lost = [o for o in self.guard.on_rtr_heard() if isinstance(o, NodeLost)]
        return lost[0].reason if lost else None

    def expect_state(self, state: NmtState | None) -> None:
        """The node is adopted in ``state`` (a pair's take-over): guarding expects it."""
        if self.guard is not None:
            self.guard.expect(state)

    def on_nmt_command(self, command: str) -> None:
        if self.guard is not None:
            self.guard.expect(NMT_EXPECTS[command])

    def on_sign_of_life(self, now: float, configuring: bool) -> None:
        """Another frame of the node (an SDO answer) while it is being ``configuring``: a node
        answering its configuration is not lost, however long the configuration takes."""
        if self.guard is not None and configuring:
            self.guard.on_sign_of_life(now)
