"""The process-data link check by the guarding bit (AP05 manual 5.5.5, 5.3.2, 5.3.3), as a
plain state machine: no I/O, no clock (``now`` is given; the caller uses the bus clock).

Imports: the standard library and canopen_gateway.canopen.states.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen_gateway.canopen.states import LinkState


@dataclass(frozen=True)
class LinkOk:
    """Change: the device echoes the guarding bit (again)."""


@dataclass(frozen=True)
class LinkFault:
    """Change: the device stopped echoing the guarding bit."""

    reason: str


class GuardingBitCheck:
    """Process-data link check by the guarding bit (AP05 manual 5.5.5, 5.3.2, 5.3.3).

    The device copies bit 8 of the control word it receives (5F0Ch, in the RPDOs) into bit 8 of
    its status word (5F19h) and sends it with its next TPDO. The gateway toggles the bit it sends
    and checks that the status words echo it.

    One toggle is in flight at a time: ``next_bit`` toggles the bit only when the previous toggle
    has been echoed (or nothing was sent yet) and otherwise repeats it, so every echo answers
    exactly one toggle, whatever the RPDO and TPDO rates. The first bit sent is 1: the status
    word starts with bit 8 = 0 after power-on (AP05 manual 5.3.1.3 example: status word 0), so an
    echo of 0 could not be told from a device that never received anything.

    ===========  ===============================================================  ========  =========
    state        event                                                            next      outputs
    ===========  ===============================================================  ========  =========
    any          next_bit (RPDO sent)                                             same      (expectation recorded)
    any          heard (another master's RPDO, a new bit)                         same      (expectation recorded)
    any          status bit 8 == bit last sent                                    OK        LinkOk if not OK before
    UNKNOWN/OK   status bit 8 != bit last sent, more than N in a row               FAULT     LinkFault
    UNKNOWN/OK   poll, a toggle sent at t is unechoed and now > t + T              FAULT     LinkFault
    FAULT        status bit 8 == bit last sent                                    OK        LinkOk
    ===========  ===============================================================  ========  =========

    A status word that does not echo is a *missed echo* (the first one or two after a toggle are
    normal: that TPDO may have left before the RPDO was processed; hence the tolerance N).
    Status words received before anything was sent are ignored.
    """

    def __init__(self, tolerance_missed: int = 3, tolerance_s: float = 1.0):
        if tolerance_missed < 0:
            raise ValueError("tolerance_missed must be >= 0")
        if tolerance_s <= 0:
            raise ValueError("tolerance_s must be > 0")
        self.tolerance_missed = tolerance_missed
        self.tolerance_s = tolerance_s
        self.state: LinkState = LinkState.UNKNOWN
        self.bit: int | None = None  # last bit sent
        self.pending_since_s: float | None = None  # when the unechoed toggle was first sent
        self.consecutive_missed = 0
        self.missed = 0
        self.echoes = 0
        self.sent = 0
        self.faults = 0

    @property
    def deadline_s(self) -> float | None:
        if self.pending_since_s is None or self.state is LinkState.FAULT:
            return None
        return self.pending_since_s + self.tolerance_s

    def next_deadline(self) -> float | None:
        return self.deadline_s

    def next_bit(self, now: float) -> int:
        """The guarding bit to put into the control word of the RPDO about to be sent."""
        if self.bit is None:
            self.bit = 1
            self.pending_since_s = now
        elif self.pending_since_s is None:
            self.bit ^= 1
            self.pending_since_s = now
        self.sent += 1
        return self.bit

    def heard(self, bit: int, now: float) -> None:
        """Another master sent ``bit`` (a pair's standby hears the active gateway's RPDO): the
        expectation follows it as if sent here, so the echoes judge the link the same way and
        a take-over toggles on from it."""
        if bit != self.bit:
            self.bit = bit
            self.pending_since_s = now

    def on_status(self, bit: int, now: float) -> list[LinkOk | LinkFault]:
        """Bit 8 of a status word just received in a TPDO."""
        if self.bit is None:
            return []
        if (bit & 1) == self.bit:
            self.consecutive_missed = 0
            if self.pending_since_s is not None:
                self.echoes += 1
                self.pending_since_s = None
            if self.state is not LinkState.OK:
                self.state = LinkState.OK
                return [LinkOk()]
            return []
        self.missed += 1
        self.consecutive_missed += 1
        if self.consecutive_missed > self.tolerance_missed and self.state is not LinkState.FAULT:
            return self._fault(
                f"guarding bit not echoed in {self.consecutive_missed} status words in a row"
            )
        return []

    def poll(self, now: float) -> list[LinkOk | LinkFault]:
        deadline = self.deadline_s
        if deadline is not None and now > deadline:
            return self._fault(f"guarding bit not echoed for more than {self.tolerance_s:g} s")
        return []

    def reset(self) -> None:
        """Forget the expectation (the node rebooted or was lost): state UNKNOWN."""
        self.state = LinkState.UNKNOWN
        self.bit = None
        self.pending_since_s = None
        self.consecutive_missed = 0

    def _fault(self, reason: str) -> list[LinkOk | LinkFault]:
        self.state = LinkState.FAULT
        self.faults += 1
        return [LinkFault(reason)]
