"""What the active gateway of a hot-standby pair does without changing its role (the ``active``
rows of ``flying_master.DOES``), and its own timers: the end of its time slot when it
negotiates again, its 76h every detect cycle, the answer its 75h waits for.

=====================================  ==================================================
heard / timer while active             does
=====================================  ==================================================
73h                                    answers one 71h
72h                                    waits its slot (once), then 71h
76h                                    sends 72h, waits its slot, then 71h
71h that loses, another sender of the  answers 71h: the worse master stands by on it (one
logical heartbeat                      per heartbeat period, ``OUTCLAIMS_PER_CYCLE`` per
                                       detect cycle: a device stuck on that COB-ID)
72h, 76h, 71h that loses               75h, once per take-over time: a 74h must answer it
                                       within ``answer_s``, else its frames do not arrive
74h                                    (its frames arrive)
its slot over                          71h
detect cycle over                      76h
=====================================  ==================================================

Imports: bus.pair.protocol (its vocabulary) and the standard library. No I/O, no clock.
"""

from __future__ import annotations

from collections.abc import Callable

from canopen_gateway.bus.pair.protocol import (
    COB_ACTIVE_MASTER_RESPONSE,
    COB_DETECT_CAPABLE,
    COB_FORCE_NEGOTIATION,
    COB_NEGOTIATION_REQUEST,
    Action,
    Heard,
    Notice,
    PairTiming,
    Send,
)

#: an active gateway answers another sender of the logical heartbeat with its claim at most
#: this many times per detect cycle (a device stuck on that COB-ID costs a few frames)
OUTCLAIMS_PER_CYCLE = 3


class ActiveDuties:
    """The active role's answers and timers (see the module docstring). ``who``: the last
    claim heard, in words, for the log."""

    def __init__(self, priority: int, node_id: int, timing: PairTiming, who: Callable[[], str]):
        self.priority, self.node_id, self.timing = priority, node_id, timing
        self._who = who
        self.claim_s: float | None = None  # the end of its slot, then 71h
        self.detect_s: float | None = None  # the next 76h
        self.probe_s: float | None = None  # its 75h unanswered until then
        self._probed_s = float("-inf")  # when it last sent a 75h
        self._outclaimed: list[float] = []  # when it answered another master (this cycle)
        self.outclaims = 0  # claims answering another master met while active

    def begin(self, now: float) -> None:
        """It becomes active: its detect cycle starts."""
        self.detect_s = now + self.timing.detect_cycle_s

    def end(self) -> None:
        """It is no longer active: no timer of the role runs."""
        self.claim_s = self.detect_s = self.probe_s = None

    def next_deadline_s(self) -> float | None:
        times = [t for t in (self.claim_s, self.detect_s, self.probe_s) if t is not None]
        return min(times) if times else None

    def due(self, now: float) -> Heard | None:
        """The timer due now, if any (its unanswered 75h first)."""
        for at, heard in (
            (self.probe_s, Heard.UNANSWERED),
            (self.claim_s, Heard.CLAIM_DUE),
            (self.detect_s, Heard.DETECT_DUE),
        ):
            if at is not None and now >= at:
                return heard
        return None

    def claim_frame(self) -> Send:
        return Send("send", COB_ACTIVE_MASTER_RESPONSE, bytes((self.priority, self.node_id)))

    # ``DOES`` (called with ``now``)
    def answer(self, now: float) -> list[Action]:
        return [self.claim_frame()]

    def join_slot(self, now: float) -> list[Action]:
        if self.claim_s is None:  # a 72h heard within our slot starts nothing new
            self.claim_s = now + self.timing.slot_s(self.priority, self.node_id)
        return []

    def negotiate_again(self, now: float) -> list[Action]:
        if self.claim_s is not None:
            return []
        self.join_slot(now)
        return [Send("send", COB_NEGOTIATION_REQUEST, b"")]

    def outclaim(self, now: float) -> list[Action]:
        """Another master met (a worse claim, another sender of the logical heartbeat): our
        claim answers it, and the worse one stands by on hearing it."""
        self._outclaimed = [t for t in self._outclaimed if now - t < self.timing.detect_cycle_s]
        recent = self._outclaimed[-1] if self._outclaimed else float("-inf")
        if len(self._outclaimed) >= OUTCLAIMS_PER_CYCLE or now - recent < self.timing.heartbeat:
            return []
        self._outclaimed.append(now)
        self.outclaims += 1
        text = f"pair: another master is on the bus (last claim: {self._who()}): answered with our claim"
        return [Notice("notice", "outclaim", text), self.claim_frame()]

    def probe(self, now: float) -> list[Action]:
        """Another master met: make sure our frames reach the bus (a 75h draws a 74h)."""
        if self.probe_s is not None or now - self._probed_s < self.timing.takeover_s:
            return []
        self._probed_s, self.probe_s = now, now + self.timing.answer_s
        return [Send("send", COB_DETECT_CAPABLE, b"")]

    def answered(self, now: float) -> list[Action]:
        self.probe_s = None
        return []

    def claim(self, now: float) -> list[Action]:
        self.claim_s = None
        return [self.claim_frame()]

    def detect(self, now: float) -> list[Action]:
        self.detect_s = now + self.timing.detect_cycle_s
        return [Send("send", COB_FORCE_NEGOTIATION, b"")]
