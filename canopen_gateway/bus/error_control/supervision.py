"""Node supervision as plain state machines: heartbeat consumer and node guarding master
(the guarding-bit check of process data is in ``bus.error_control.guarding_bit``). Both stand
on one base, ``Supervisor``: the liveness of the node, the NMT state it reported, and the
queries ``alive``, ``lost`` and ``deadline_s``.

Rule 1: everything that decides whether a node (or its process-data link) is alive lives here,
with each transition in a table next to the manual section it implements.
Rule 2: nothing here does I/O or knows the time by itself. The caller (the bus driver) feeds
received frames and the current monotonic time ``now`` (seconds) in, and gets back a list of
outputs: *actions* (a frame the caller must send, e.g. ``SendGuardRtr``) and *changes* (what
happened, e.g. ``NodeLost``). ``next_deadline()`` tells the caller when to ``poll`` next.

Timeout edges, one convention for every machine in this file: a timeout of ``T`` seconds
measured from ``t0`` expires strictly *after* ``t0 + T``. At ``now == t0 + T`` the node is still
alive; at the next representable instant it is lost. Scheduled sends are due *at* their time
(``now >= due``).

Imports: the standard library and canopen_gateway.canopen.states (the one NmtState / LinkState). Must not
import python-can, canopen, asyncio, logging or any other gateway module.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from canopen_gateway.canopen.states import REPORTED_STATES as _REPORTED_STATES
from canopen_gateway.canopen.states import NmtState

# --------------------------------------------------------------------------- NMT states


class Liveness(StrEnum):
    """Whether a supervised node is answering."""

    UNKNOWN = "unknown"  # not heard of yet (or just booted: monitoring restarts)
    ALIVE = "alive"
    LOST = "lost"


# --------------------------------------------------------------------------- outputs


@dataclass(frozen=True)
class SendGuardRtr:
    """Action: send a remote frame (RTR, DLC 1) on COB-ID 700h + node id (SGH10 manual 4.5.2)."""


@dataclass(frozen=True)
class NodeAlive:
    """Change: the node answers again (or for the first time), in this NMT state."""

    nmt_state: NmtState


@dataclass(frozen=True)
class NodeLost:
    """Change: no valid heartbeat / guarding answer within the timeout."""

    reason: str


@dataclass(frozen=True)
class NmtStateChanged:
    """Change: the NMT state the node reports differs from the one it reported before."""

    old: NmtState | None
    new: NmtState


@dataclass(frozen=True)
class BootUpSeen:
    """Change: the node sent its boot-up message (700h + node id, byte 00h)."""


@dataclass(frozen=True)
class InvalidStateByte:
    """Change: a heartbeat / guarding answer carried a state value DS-301 does not define."""

    byte: int

    def __str__(self) -> str:
        return f"state byte 0x{self.byte:02X} is not an NMT state (DS-301: 0, 4, 5, 127)"


@dataclass(frozen=True)
class ToggleError:
    """Change: a guarding answer repeated the previous toggle bit; the answer is not valid."""

    expected: int
    received: int
    count: int

    def __str__(self) -> str:
        return (
            f"guarding answer toggle bit {self.received}, expected {self.expected} "
            f"({self.count} in a row)"
        )


@dataclass(frozen=True)
class WrongState:
    """Change: a guarding answer reported another NMT state than the expected one."""

    expected: NmtState
    received: NmtState
    count: int

    def __str__(self) -> str:
        return (
            f"guarding answer reports {_state_word(self.received)}, expected "
            f"{_state_word(self.expected)} ({self.count} in a row)"
        )


def _state_word(state: NmtState) -> str:
    """``pre-operational`` for NmtState.PRE_OPERATIONAL: the words of the manuals."""
    return state.name.lower().replace("_", "-")


Output = (
    SendGuardRtr
    | NodeAlive
    | NodeLost
    | NmtStateChanged
    | BootUpSeen
    | InvalidStateByte
    | ToggleError
    | WrongState
)


# --------------------------------------------------------------------------- the shared base


class Supervisor:
    """What both machines below share: the liveness of the supervised node (``state``), the
    NMT state it last reported (``nmt_state``), the counts of losses and boot-ups, and the
    queries on them. Each machine says until when the node counts as alive (``deadline_s``);
    a timeout expires strictly after it (the convention of this file)."""

    def __init__(self) -> None:
        self.state: Liveness = Liveness.UNKNOWN
        self.nmt_state: NmtState | None = None
        self.losses = 0
        self.bootups = 0

    # -- queries
    @property
    def lost(self) -> bool:
        return self.state is Liveness.LOST

    @property
    def alive(self) -> bool:
        return self.state is Liveness.ALIVE

    @property
    def deadline_s(self) -> float | None:
        """Last instant at which the node still counts as alive (None: no timeout running)."""
        raise NotImplementedError

    # -- transitions both machines make
    def _expired(self, now: float) -> bool:
        deadline = self.deadline_s
        return deadline is not None and now > deadline

    def _lose(self, reason: str) -> NodeLost:
        self.state = Liveness.LOST
        self.losses += 1
        return NodeLost(reason)

    def _become_alive(self, nmt_state: NmtState) -> list[Output]:
        if self.state is Liveness.ALIVE:
            return []
        self.state = Liveness.ALIVE
        return [NodeAlive(nmt_state)]

    def _report(self, nmt_state: NmtState) -> list[Output]:
        """The node reports ``nmt_state`` (after a boot-up: PRE-OPERATIONAL, SGH10 manual
        4.2.1.1); a change is an output."""
        if nmt_state == self.nmt_state:
            return []
        old, self.nmt_state = self.nmt_state, nmt_state
        return [NmtStateChanged(old, nmt_state)]


# --------------------------------------------------------------------------- heartbeat consumer


class HeartbeatConsumer(Supervisor):
    """Watches the heartbeat of one producer node (SGH10 manual 4.5.3, DS-301 heartbeat).

    The node sends ``700h + node id`` with its NMT state every ``producer_ms`` (object 1017h).
    The node is lost when no heartbeat arrives within ``multiple * producer_ms``.

    ====================  ========================================  ========  ======================
    state                 event                                     next      outputs
    ====================  ========================================  ========  ======================
    UNKNOWN               heartbeat (state s)                       ALIVE     NodeAlive(s), NmtStateChanged
    ALIVE                 heartbeat (state s)                       ALIVE     NmtStateChanged if s changed
    ALIVE                 poll, now > last heartbeat + timeout      LOST      NodeLost
    LOST                  heartbeat (state s)                       ALIVE     NodeAlive(s), NmtStateChanged if changed
    any                   boot-up (byte 00h)                        UNKNOWN   BootUpSeen, NmtStateChanged(-> PRE_OPERATIONAL)
    any                   boot-up, with bootup_grace_s              ALIVE     same, and NodeAlive if not alive before
    ALIVE (after boot)    poll, now > boot-up + bootup_grace_s      LOST      NodeLost (no heartbeat came at all)
    any                   byte not 00h/04h/05h/7Fh                  same      InvalidStateByte (ignored)
    ====================  ========================================  ========  ======================

    Monitoring starts with the first heartbeat (DS-301) and restarts after a boot-up: a node that
    just booted may have 1017h = 0 until the gateway configures it, so a boot-up is not treated
    as a heartbeat (no false loss during configuration). A node that never sends anything stays
    UNKNOWN; reporting that is the lifecycle's boot timeout. With ``bootup_grace_s`` the boot-up
    counts as a sign of life instead, and the first heartbeat must follow within that grace
    (long enough to configure 1017h): a node that dies during its configuration is then lost.
    """

    def __init__(
        self, producer_ms: int, multiple: float = 1.5, bootup_grace_s: float | None = None
    ):
        if producer_ms <= 0:
            raise ValueError(
                f"producer_ms must be > 0 (1017h = 0 disables heartbeat), got {producer_ms}"
            )
        if multiple < 1.0:
            raise ValueError(f"multiple must be >= 1.0, got {multiple}")
        if bootup_grace_s is not None and bootup_grace_s <= 0:
            raise ValueError(f"bootup_grace_s must be > 0 or None, got {bootup_grace_s}")
        super().__init__()
        self.producer_ms = producer_ms
        self.multiple = multiple
        self.bootup_grace_s = bootup_grace_s
        self._grace_until_s: float | None = None
        self.timeout_s: float = producer_ms * multiple / 1000.0
        self.last_heartbeat_s: float | None = None
        self.heartbeats = 0
        self.invalid_frames = 0

    # -- queries
    @property
    def deadline_s(self) -> float | None:
        """Last instant at which the node still counts as alive (None when not monitoring)."""
        if self.state is not Liveness.ALIVE:
            return None
        if self.last_heartbeat_s is None:
            return self._grace_until_s
        return self.last_heartbeat_s + self.timeout_s

    def next_deadline(self) -> float | None:
        """When ``poll`` may next change something (None: only a received frame can)."""
        return self.deadline_s

    # -- events
    def on_frame(self, byte: int, now: float) -> list[Output]:
        """A frame on 700h + node id: boot-up (00h) or heartbeat (state byte)."""
        if byte == NmtState.BOOTUP:
            return self.on_bootup(now)
        return self.on_heartbeat(byte, now)

    def on_heartbeat(self, byte: int, now: float) -> list[Output]:
        try:
            new = NmtState(byte & 0x7F)  # DS-301: bit 7 of a heartbeat is reserved (0)
        except ValueError:
            new = None
        if new is None or new not in _REPORTED_STATES:
            if byte == NmtState.BOOTUP:
                return self.on_bootup(now)
            self.invalid_frames += 1
            return [InvalidStateByte(byte)]
        self.heartbeats += 1
        self.last_heartbeat_s = now
        return [*self._become_alive(new), *self._report(new)]

    def on_bootup(self, now: float) -> list[Output]:
        self.bootups += 1
        self.last_heartbeat_s = None
        out: list[Output] = [BootUpSeen()]
        # SGH10 manual 4.2.1.1: after the boot-up message the device is PRE-OPERATIONAL.
        if self.bootup_grace_s is None:
            self.state = Liveness.UNKNOWN
            self._grace_until_s = None
        else:
            self._grace_until_s = now + self.bootup_grace_s
            out += self._become_alive(NmtState.PRE_OPERATIONAL)
        return out + self._report(NmtState.PRE_OPERATIONAL)

    def poll(self, now: float) -> list[Output]:
        if not self._expired(now):
            return []
        if self.last_heartbeat_s is None:
            return [self._lose(f"no heartbeat within {self.bootup_grace_s:g} s of the boot-up")]
        return [self._lose(f"no heartbeat for more than {self.timeout_s * 1000:g} ms")]


# --------------------------------------------------------------------------- node guarding


class NodeGuardingMaster(Supervisor):
    """The master side of node guarding (DS-301; AP05 manual 5.5.2, SGH10 manual 4.5.2).

    Every guard time the master sends an RTR on ``700h + node id``; the node answers one byte:
    bit 7 toggle, bits 6..0 NMT state (4, 5 or 127). The first answer after guarding is activated
    has toggle 0, then the toggle alternates. Life time = guard time x life time factor (100Ch x
    100Dh): without a valid answer for that long, the node is lost.

    ===========  =================================================  ========  ==========================
    state        event                                              next      outputs
    ===========  =================================================  ========  ==========================
    any          poll, now >= next RTR time                         same      SendGuardRtr (first poll activates)
    UNKNOWN      answer, toggle ok, state ok                        ALIVE     NodeAlive, NmtStateChanged
    ALIVE        answer, toggle ok, state ok                        ALIVE     NmtStateChanged if changed
    LOST         answer, toggle ok, state ok                        ALIVE     NodeAlive
    any          answer with the previous answer's toggle           same      ToggleError (answer not valid)
    any          answer with state != expected                      same      WrongState (answer not valid)
    UNKNOWN      poll, now > activation/boot-up + life time         LOST      NodeLost
    ALIVE        poll, now > last valid answer + life time          LOST      NodeLost
    any          boot-up                                            UNKNOWN   BootUpSeen (toggle restarts at 0)
    not LOST     sign of life (SDO answer during configuration)     same      life time runs from now
    ALIVE        another master's RTR heard (we only listen), more  LOST      NodeLost
                 than life time factor of them without a valid answer
    ===========  =================================================  ========  ==========================

    Listening (a pair's standby): the owner does not ``poll`` (no RTR, no life time of ours:
    nobody may be guarding), it feeds the answers it hears (the toggle is followed from the first
    one heard, whichever it carries: the other master's guarding may be anywhere) and the
    other master's RTRs (``on_rtr_heard``): the node is lost when more RTRs than the life time
    factor went unanswered, the life time counted in the other master's own guard cycles.

    DS-301: "if two consecutive responses have the same value of the toggle-bit, the new
    response should be handled as if it was not received": the expected toggle is always the
    inverse of the last answer's, so one lost answer costs one ToggleError, not a stuck error.
    A wrong NMT state is a node-guarding error too: the answer is not valid (it does not renew
    the life time) but its state is still reported with NmtStateChanged. ``expected_state`` is
    what the master commanded (None: any of 4/5/127 is accepted); the owner sets it.
    """

    def __init__(self, guard_time_ms: int, life_time_factor: int):
        if guard_time_ms <= 0 or life_time_factor <= 0:
            # SGH10 manual 4.5.2: guarding is deactivated if 100Ch or 100Dh is 0.
            raise ValueError(
                f"node guarding needs guard_time_ms > 0 and life_time_factor > 0 "
                f"(got {guard_time_ms} ms x {life_time_factor}); 0 deactivates guarding"
            )
        super().__init__()
        self.guard_time_ms = guard_time_ms
        self.life_time_factor = life_time_factor
        self.guard_time_s: float = guard_time_ms / 1000.0
        self.life_time_s: float = guard_time_ms * life_time_factor / 1000.0
        self.expected_state: NmtState | None = None
        self.guarding_started = False
        self.expected_toggle = 0  # DS-301: first answer after activation carries toggle 0
        self.last_valid_s: float | None = None  # or activation / boot-up time
        self.next_rtr_s: float | None = None
        self.rtr_sent = 0
        self.answers = 0
        self.toggle_errors = 0
        self.state_errors = 0
        self.last_answer_valid: bool | None = None
        self.unanswered_rtrs = 0  # another master's RTRs heard since the last valid answer

    # -- queries
    @property
    def deadline_s(self) -> float | None:
        """Last instant without a valid answer at which the node still counts as not lost."""
        if not self.guarding_started or self.state is Liveness.LOST or self.last_valid_s is None:
            return None
        return self.last_valid_s + self.life_time_s

    def next_deadline(self) -> float | None:
        times = [t for t in (self.next_rtr_s, self.deadline_s) if t is not None]
        return min(times) if times else None

    def expect(self, state: NmtState | None) -> None:
        """The state the node must report from now on (None: any valid state)."""
        self.expected_state = state

    # -- events
    def poll(self, now: float) -> list[Output]:
        out: list[Output] = []
        if not self.guarding_started:
            # SGH10 manual 4.5.2: guarding is enabled by the master's first RTR.
            self.guarding_started = True
            self.last_valid_s = now
            self.next_rtr_s = now
        if self._expired(now):
            out.append(
                self._lose(f"no valid guarding answer for more than {self.life_time_s * 1000:g} ms")
            )
        assert self.next_rtr_s is not None
        if now >= self.next_rtr_s:
            out.append(SendGuardRtr())
            self.rtr_sent += 1
            nxt = self.next_rtr_s + self.guard_time_s
            self.next_rtr_s = nxt if nxt > now else now + self.guard_time_s
        return out

    def on_response(self, byte: int, now: float) -> list[Output]:
        """A guarding answer (data frame on 700h + node id, byte 0)."""
        self.answers += 1
        toggle = (byte >> 7) & 1
        raw_state = byte & 0x7F
        out: list[Output] = []
        valid = True
        if not self.guarding_started and self.answers == 1:
            # the first answer heard while another master guards the node (a pair's standby
            # joining a running bus): its toggle is where that master's guarding is, not an error
            self.expected_toggle = toggle
        if toggle != self.expected_toggle:
            self.toggle_errors += 1
            out.append(ToggleError(self.expected_toggle, toggle, self.toggle_errors))
            valid = False
        self.expected_toggle = toggle ^ 1
        try:
            st = NmtState(raw_state)
        except ValueError:
            st = None
        if st is None or st not in _REPORTED_STATES:
            self.state_errors += 1
            self.last_answer_valid = False
            return [*out, InvalidStateByte(byte)]
        out += self._report(st)
        if self.expected_state is not None and st != self.expected_state:
            self.state_errors += 1
            out.append(WrongState(self.expected_state, st, self.state_errors))
            valid = False
        self.last_answer_valid = valid
        if valid:
            if not self.guarding_started:
                self.guarding_started = True
                self.next_rtr_s = now + self.guard_time_s
            self.last_valid_s = now
            self.unanswered_rtrs = 0
            out += self._become_alive(st)
        return out

    def on_rtr_heard(self) -> list[Output]:
        """Another master's guarding RTR to the node, heard while only listening."""
        if self.state is not Liveness.ALIVE:
            return []
        self.unanswered_rtrs += 1
        if self.unanswered_rtrs <= self.life_time_factor:
            return []
        return [
            self._lose(
                f"no valid guarding answer to {self.unanswered_rtrs} RTRs of the active master"
            )
        ]

    def on_sign_of_life(self, now: float) -> None:
        """Another frame of the node (an SDO answer while it is configured) shows it is there:
        the life time runs from now. Guarding answers stay the only way to become ALIVE."""
        if self.guarding_started and self.state is not Liveness.LOST and self.last_valid_s is not None:
            self.last_valid_s = max(self.last_valid_s, now)

    def on_bootup(self, now: float) -> list[Output]:
        """The node restarted: its toggle starts again at 0, the life time runs from now."""
        self.bootups += 1
        self.expected_toggle = 0
        self.state = Liveness.UNKNOWN
        if self.guarding_started:
            self.last_valid_s = now
        return [BootUpSeen(), *self._report(NmtState.PRE_OPERATIONAL)]
