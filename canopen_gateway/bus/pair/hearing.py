"""What one gateway of a hot-standby pair heard of the bus and of the active master, and when:
the facts the role machine (``flying_master.py``) decides on, on the monotonic clock.

Rule: plain bookkeeping, no role. Every time here is the caller's ``now`` (the bus clock: the
monotonic clock as far as the reader got through the frames), never a wall clock; a time
reported from the past or the future of what was already heard is taken as it is only when it
is plausible (``heard``: a frame time older than the last one heard changes nothing).

* ``heard_s``: the last frame of anyone but this gateway (a frame handed to the machine, or the
  time the driver took its last frame); ``active_heard_s``: the last sign of the active master
  (its logical heartbeat, a claim, its 76h);
* the detection window of a gateway that listens starts with the first frame its bus delivers
  after it began listening (a process that starts while its bus stalls does not negotiate
  against a running pair); nothing at all heard for ``silent_s`` is a silent bus;
* the standby's doubt: the master silent and no frame heard since its next two heartbeats were
  due (a dead master on a quiet bus, or this gateway's cable cut): it waits for a frame until the
  bus must have talked (``PairTiming.doubt_s``), then counts itself cut off.

Imports: bus.pair.protocol (the pair's times) and the standard library.
"""

from __future__ import annotations

from canopen_gateway.bus.pair.protocol import PairTiming


class Hearing:
    """When this gateway heard the bus and the active master (see the module docstring)."""

    def __init__(self, timing: PairTiming):
        self.timing = timing
        #: the last time anyone but this gateway was heard (a frame, the reader's last frame)
        self.heard_s: float | None = None
        #: the last time the active master was heard (its heartbeat, its 71h or 76h)
        self.active_heard_s: float | None = None
        #: when this gateway last began listening (its start, or back from an outage)
        self.listened_s = float("inf")
        #: the first frame heard since it began listening (None: its bus delivered none yet)
        self.first_s: float | None = None

    def heard(self, at_s: float) -> bool:
        """A frame of anyone but this gateway at ``at_s``; False when it is not newer."""
        if self.heard_s is not None and at_s <= self.heard_s:
            return False
        self.heard_s = at_s
        if self.first_s is None and at_s >= self.listened_s:
            self.first_s = at_s
        return True

    def master(self, now: float) -> None:
        self.active_heard_s = now

    def listen(self, now: float, delivered: bool) -> None:
        """It begins listening; ``delivered``: a frame heard just now brought it back."""
        self.listened_s = now
        self.first_s = now if delivered else None

    @property
    def master_heard(self) -> bool:
        """An active master was heard since this gateway last began listening."""
        heard = self.active_heard_s
        return heard is not None and heard >= self.listened_s

    def detection_over(self, now: float) -> bool | None:
        """Listening: True when the detection time has run since its bus delivered a frame (or
        nothing was heard for ``silent_s``: a silent bus); None while it must look again."""
        t = self.timing
        if self.first_s is not None:
            return True if now >= self.first_s + t.detect_s else None
        return True if now >= self.listened_s + t.silent_s else None

    def detection_due_s(self, now: float) -> float:
        """When to look again while listening."""
        t = self.timing
        if self.first_s is not None:
            return self.first_s + t.detect_s
        return min(self.listened_s + t.silent_s, now + t.heartbeat / 4)

    def master_gone(self) -> bool:
        """A frame was heard after the active master's next two heartbeats were due: the bus is
        alive and the master silent (a frame before that may precede a cut cable, and one late
        heartbeat must not make a cut look like a dead master)."""
        ref = self.active_heard_s if self.active_heard_s is not None else float("-inf")
        return self.heard_s is not None and self.heard_s > ref + 2 * self.timing.heartbeat

    def doubt_until_s(self, now: float) -> float:
        """The master silent, nothing heard since: until when the standby waits for a frame
        before it counts itself cut off."""
        ref = self.active_heard_s if self.active_heard_s is not None else now
        return max(now + self.timing.takeover_s, ref + self.timing.doubt_s)

    def within(self, now: float, window_s: float) -> bool:
        """Anyone heard within ``window_s`` before ``now``."""
        return self.heard_s is not None and now - self.heard_s < window_s
