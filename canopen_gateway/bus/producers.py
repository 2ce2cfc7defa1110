"""The master's own periodic frames: SYNC (DS-301 7.2.5; SGH10 manual 4.3.2) and its
heartbeat (700h + master node id, state 05h). Plain schedules fed with ``now``: due at
``start``, then every ``period_s``; a late tick sends once and the schedule catches up (no
burst of missed frames).

Imports: the standard library only.
"""

from __future__ import annotations


class Periodic:
    """A frame due every ``period_s`` seconds from ``start_s``."""

    def __init__(self, period_s: float, start_s: float):
        if period_s <= 0:
            raise ValueError("period_s must be > 0")
        self.period_s = period_s
        self.next_s = start_s
        self.sent = 0

    def next_deadline(self) -> float:
        return self.next_s

    def due(self, now: float) -> bool:
        """True when the frame must go out now; the next one is then scheduled."""
        if now < self.next_s:
            return False
        self.next_s += self.period_s
        if self.next_s <= now:  # late by more than a period: restart the schedule from now
            self.next_s = now + self.period_s
        self.sent += 1
        return True
