"""When a node the gateway waits for is probed: its device type (1000h) read, to find a node that
is already running (it sends no boot-up: the gateway restarted, the node was replugged).

A node waiting (lifecycle WAITING) is probed every ``probe_period_s`` from ``next_s``, not before
the recheck of a refused device (``NodeLifecycle.recheck_at_s``), and not at all while it waits
to be heard (a pair's node lost while it ran: it says itself when it is back, no probe to
reconfigure it). A node heard alive with no boot-up seen is probed at once, unless a probe ended
less than ``min(1 s, probe_period_s)`` before (``rested``: a healed split resolves first).

Rule: the schedule only; the node (``bus/node/node.py``) queues the transfer and reads the
answer (``sdo_done.probe_done``). No I/O, no clock.

Imports: bus.node.lifecycle (its states and recheck). Nothing else of the gateway.
"""

from __future__ import annotations

from canopen_gateway.bus.node.lifecycle import LifecycleState, NodeLifecycle


class Probes:
    """The probe schedule of one node (see the module docstring)."""

    def __init__(self, period_s: float):
        self.period_s = period_s
        self.next_s: float | None = None  # the next probe, while waiting (None: none planned)
        self.last_end_s: float | None = None  # when the last probe ended (answered or not)

    def at(self, t: float) -> None:
        """The next probe at ``t``."""
        self.next_s = t

    def later(self, now: float) -> None:
        """The next probe one period from ``now`` (the cadence after a probe or a loss)."""
        self.next_s = now + self.period_s

    def ended(self, now: float, again_s: float | None) -> None:
        """A probe ended at ``now``; ``again_s``: when to probe again (None: as planned)."""
        self.last_end_s, self.next_s = now, again_s or self.next_s

    def rested(self, now: float) -> bool:
        """No probe ended within ``min(1 s, probe_period_s)``: a node heard may be probed."""
        last = self.last_end_s
        return last is None or now - last >= min(1.0, self.period_s)

    def due_s(self, lifecycle: NodeLifecycle, heard_back: bool) -> float | None:
        """When the next probe is due: in WAITING at ``next_s``, not before the recheck of a
        refused device; ``heard_back``: it waits to be heard instead (no probe)."""
        if lifecycle.state is not LifecycleState.WAITING or self.next_s is None or heard_back:
            return None
        recheck = lifecycle.recheck_at_s
        return self.next_s if recheck is None else max(self.next_s, recheck)
