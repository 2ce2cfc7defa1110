"""The life of one node as the master sees it: waiting, booting, configuring, operational.

Rule 1: every decision about when to configure a node, which SDO write comes next, when to
retry a failed write and when to start the node lives here. The state changes are a table the
code reads (``TRANSITIONS``, shown in the docstring of ``NodeLifecycle``), as h11's
``_state.py``: a change the table does not define raises ``LifecycleError`` (our own misuse);
an event of the device or of the driver that means nothing in the current state is ignored and
counted (``ignored``).
Rule 2: nothing here does I/O or reads a clock. The driver asks ``next_action(now)`` what to do
(an SDO write, an NMT command, or wait), does it, and reports the outcome
(``on_step_result``, ``on_nmt_sent``); it also reports what it observed (``on_bootup``,
``on_found``, ``on_lost``) and calls ``poll(now)`` for the boot timeout. Every event method
returns the list of changes it caused.

The steps themselves (``ConfigStep``, ``build_boot_steps``) come from ``device/boot_steps.py``;
the states, actions and changes it speaks in from ``bus/node/lifecycle_actions.py``.

Imports: canopen_gateway.device.boot_steps (the step type), canopen_gateway.bus.node.lifecycle_actions,
canopen_gateway.bus.transitions (the table's rows), canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref and the standard library.
Must not import python-can, asyncio, logging, config or any northbound module.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from canopen_gateway.bus.node.lifecycle_actions import (
    IDENTITY_ABSENT,
    IDENTITY_NAMES,
    Action,
    BootTimeout,
    Change,
    Configured,
    IdentityNotCompared,
    LifecycleState,
    ReadIdentity,
    SendNmt,
    StateChanged,
    StepFailed,
    StepSkipped,
    Wait,
    WriteStep,
    WrongDevice,
)
from canopen_gateway.bus.transitions import transition_table
from canopen_gateway.canopen.cia301 import NmtCommand, abort_text
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.device.boot_steps import ConfigStep

#: what the lifecycle speaks in is defined in ``lifecycle_actions`` and read from here too
__all__ = [
    "LifecycleState",
    "Wait",
    "WriteStep",
    "SendNmt",
    "ReadIdentity",
    "Action",
    "IDENTITY_NAMES",
    "IDENTITY_ABSENT",
    "StateChanged",
    "StepFailed",
    "StepSkipped",
    "BootTimeout",
    "WrongDevice",
    "IdentityNotCompared",
    "Configured",
    "Change",
    "Backoff",
    "LifecycleEvent",
    "LifecycleError",
    "NodeLifecycle",
    "RECHECK_BACKOFF",
    "TRANSITIONS",
]

# --------------------------------------------------------------------------- machine


@dataclass(frozen=True)
class Backoff:
    """Exponential retry delay: ``initial_s * factor ** (attempt - 1)``, capped at ``max_s``."""

    initial_s: float = 0.5
    factor: float = 2.0
    max_s: float = 30.0

    def delay_s(self, attempt: int) -> float:
        if attempt < 1:
            return 0.0
        return min(self.max_s, self.initial_s * self.factor ** (attempt - 1))


#: A refused device (1000h or 1018h not what the file says) is checked again at its next
#: boot-up, or when a probe finds it running after this delay: 1 min, 2 min, 4 min ... 16 min
#: (not at each of its heartbeats: every check sends it NMT pre-operational and reads 1018h).
RECHECK_BACKOFF = Backoff(initial_s=60.0, factor=2.0, max_s=960.0)


class LifecycleEvent(StrEnum):
    """What moves the node from one state to another (the columns of ``TRANSITIONS``)."""

    BOOTUP = "boot-up"  # a boot-up message (SGH10 manual 4.2.2)
    FOUND = "found"  # the node answers although no boot-up was seen
    CONFIGURE = "configure"  # the node is PRE-OPERATIONAL: configuration starts
    START_SENT = "NMT start sent"  # every step done, NMT start went out
    LOST = "lost"  # supervision lost the node
    WRONG_IDENTITY = "wrong identity"  # 1018h holds other values than the EDS
    LISTEN = "listen"  # another master manages the node (a pair's standby): only heard
    ADOPTED = "adopted"  # a pair's take-over: heard started, taken as it is
    TAKEN_OVER = "taken over"  # a pair's take-over: not heard started, found and configured
    RESUMED = "resumed"  # a pair's, heard operational with no boot-up seen: taken as it runs


_W, _B, _C, _O, _L = (
    LifecycleState.WAITING,
    LifecycleState.BOOTING,
    LifecycleState.CONFIGURING,
    LifecycleState.OPERATIONAL,
    LifecycleState.LISTENING,
)
_E = LifecycleEvent
#: (state, event) -> next state: every state change of ``NodeLifecycle`` (its docstring shows
#: the same table with the actions), written as rows (from these states, on these events, to)
TRANSITIONS: dict[tuple[LifecycleState, LifecycleEvent], LifecycleState] = transition_table(
    ((_W, _C, _O), (_E.BOOTUP,), _B),
    ((_W,), (_E.FOUND,), _B),
    ((_B,), (_E.CONFIGURE,), _C),  # NMT pre-operational sent, or the boot-up said so (4.2.1.1)
    ((_C,), (_E.START_SENT,), _O),
    ((_B, _C, _O), (_E.LOST,), _W),
    ((_C,), (_E.WRONG_IDENTITY,), _W),
    ((_W, _B, _C, _O), (_E.LISTEN,), _L),
    ((_L,), (_E.ADOPTED,), _O),
    ((_W,), (_E.RESUMED,), _O),
    ((_L,), (_E.TAKEN_OVER,), _W),
)


class LifecycleError(RuntimeError):
    """The gateway's own misuse of the machine: a change the table does not define."""


def _step_error(step: ConfigStep, abort_code: int | None) -> str:
    what = step.description or "configuration step"
    if abort_code is None:
        return f"{step.object} ({what}): no SDO answer"
    return f"{step.object} ({what}): SDO abort 0x{abort_code:08X} ({abort_text(abort_code)})"


class NodeLifecycle:
    """Boot-up handling and configuration of one node (DS-301 NMT; SGH10 manual 4.2).

    ===========  ============================================  ===========  =========================
    state        event                                         next         action / change
    ===========  ============================================  ===========  =========================
    WAITING      start                                         WAITING      boot timeout armed
    WAITING      poll, now > armed + boot timeout              WAITING      BootTimeout (once)
    WAITING      found running (probe of 1000h / supervision)  BOOTING      action: NMT pre-operational
    WAITING      found, 1000h != expected device type          WAITING      WrongDevice; recheck armed
    WAITING      found, before the recheck of a refused device WAITING      ignored (counted)
    BOOTING      NMT pre-operational sent                      CONFIGURING  action: identity 0 (or step 0)
    any          boot-up                                       CONFIGURING  (via BOOTING) action: identity 0 (or step 0)
    CONFIGURING  identity read i ok, more to read              CONFIGURING  action: identity i + 1
    CONFIGURING  identity read i: no answer                    CONFIGURING  StepFailed; action: Wait, then read i again
    CONFIGURING  identity read i: abort "does not exist"       CONFIGURING  IdentityNotCompared (first time); i + 1
    CONFIGURING  last identity read, all compared as expected  CONFIGURING  action: step 0
    CONFIGURING  last identity read, one differs / refused     WAITING      WrongDevice (not configured); recheck armed
    CONFIGURING  step i ok                                     CONFIGURING  action: step i + 1
    CONFIGURING  step i failed (abort / timeout)               CONFIGURING  StepFailed; action: Wait, then step i again
    CONFIGURING  optional step i refused (abort)               CONFIGURING  StepSkipped; action: step i + 1
    CONFIGURING  last step ok                                  CONFIGURING  action: NMT start
    CONFIGURING  NMT start sent                                OPERATIONAL  Configured
    not WAITING  lost (from supervision)                       WAITING      boot timeout re-armed
    not LISTEN.  listen (a pair's standby: another master)     LISTENING    (nothing sent, ever)
    LISTENING    boot-up, found, lost, poll, results           LISTENING    ignored (counted)
    LISTENING    adopted (take-over, heard started)            OPERATIONAL  (nothing sent)
    LISTENING    taken over (take-over, not heard started)     WAITING      boot timeout armed
    WAITING      resumed (a pair's: OPERATIONAL, no boot-up)    OPERATIONAL  (nothing sent)
    ===========  ============================================  ===========  =========================

    LISTENING is the state of a node another master manages: a pair's standby listens to the
    active gateway's work (``bus/node/listening.py`` keeps what it heard), and at a take-over
    the node is either adopted as it runs (heard started: no NMT command, no SDO) or waits to be
    found and configured as usual.

    After a boot-up the node is PRE-OPERATIONAL (SGH10 manual 4.2.1.1) and configuration starts
    at once. A node found already running may be OPERATIONAL, where COB-IDs and mappings cannot
    be changed (SGH10 manual 4.2.1.1, 4.1): it is first sent to PRE-OPERATIONAL. A boot-up in
    any state restarts the configuration from step 0; an SDO answer still in flight from before
    carries an old token and is ignored. Failed steps are retried with exponential backoff,
    without a limit: ``last_error`` says what fails.

    ``expected_identity`` (CiA 302-2 1F85h..1F88h style, from the EDS/DCF): the 1018h
    sub-indices and values the device must hold. They are read before the first step; a
    sub-index the device says does not exist (``IDENTITY_ABSENT``) is not compared; a device
    that holds other values (or refuses the read otherwise) is a wrong device: it is not
    configured and not started (``last_error``: "wrong device: vendor V product P, expected
    ...").

    A refused device (wrong identity, or a wrong device type found by a probe) is checked
    again at its next boot-up, or when found running once ``recheck_at_s`` has passed (delays
    of ``recheck``, default ``RECHECK_BACKOFF``, growing with each refusal in a row): until
    then ``may_probe`` is false and a "found" is ignored, so its heartbeats do not make it
    checked (NMT pre-operational, 1018h reads, an error line) over and over.
    """

    def __init__(
        self,
        steps: Sequence[ConfigStep],
        *,
        boot_timeout_s: float = 10.0,
        backoff: Backoff | None = None,
        expected_device_type: int | None = None,
        expected_identity: Sequence[tuple[ObjRef, int]] = (),
        recheck: Backoff = RECHECK_BACKOFF,
        resume_wait_s: float = 1.0,
    ):
        self.steps: tuple[ConfigStep, ...] = tuple(steps)
        self.expected_identity = tuple(expected_identity)
        self._identity_index = 0
        self._identity_found: dict[ObjRef, int | None] = {}
        self._identity_skipped: set[ObjRef] = set()  # this boot's reads "does not exist"
        #: identity objects the device said it does not have, over all boots (reported once)
        self.identity_absent: set[ObjRef] = set()
        self.recheck = recheck
        self.refusals = 0  # refusals in a row (wrong device), since the last configuration
        self._recheck_at: float | None = None
        self.boot_timeout_s = boot_timeout_s
        self.backoff = backoff or Backoff()
        self.expected_device_type = expected_device_type
        self.state: LifecycleState = LifecycleState.WAITING
        self.resumable = False  # lost while OPERATIONAL, no boot-up since: its configuration intact
        self.hold_until_s: float | None = None  # a pair's node found waits to be heard until then
        self.resume_wait_s = resume_wait_s
        self.last_error: str | None = None
        self.step_index = 0
        self.attempt = 0  # failures of the current step
        self.boots = 0
        self.losses = 0
        self.configurations = 0
        self.step_failures = 0
        self._token = 0
        self._in_flight: int | None = None  # token of the WriteStep handed out
        self._retry_at: float | None = None
        self._preop_pending = False
        self._boot_deadline: float | None = None
        self._waiting_since: float | None = None
        self._config_started: float | None = None
        #: events that meant nothing in the state they came in (a late answer, a second
        #: "found"...), by (state, event name): counted, not acted on
        self.ignored: dict[tuple[LifecycleState, str], int] = {}

    # -- queries
    @property
    def boot_deadline_s(self) -> float | None:
        """Last instant before the boot timeout fires (None: not armed or already fired)."""
        return self._boot_deadline

    @property
    def retry_at_s(self) -> float | None:
        return self._retry_at

    @property
    def recheck_at_s(self) -> float | None:
        """When a refused device may be checked again (None: not refused, or booted since)."""
        return self._recheck_at

    def may_probe(self, now: float) -> bool:
        """May a probe look for the node now? Not while a refused device waits its recheck."""
        return self._recheck_at is None or now >= self._recheck_at

    def next_deadline(self) -> float | None:
        times = [t for t in (self._boot_deadline, self._retry_at) if t is not None]
        return min(times) if times else None

    def next_action(self, now: float) -> Action | None:
        """What the driver must do now; the same action again until its outcome is reported."""
        if self.state is LifecycleState.BOOTING and self._preop_pending:
            return SendNmt("nmt_preop", NmtCommand.ENTER_PRE_OPERATIONAL)
        if self.state is not LifecycleState.CONFIGURING:
            return None
        if self._retry_at is not None:
            if now < self._retry_at:
                return Wait("wait", self._retry_at - now)
            self._retry_at = None
        if self._identity_index < len(self.expected_identity):
            if self._in_flight is None:
                self._token += 1
                self._in_flight = self._token
            obj = self.expected_identity[self._identity_index][0]
            return ReadIdentity("identity", obj, self._in_flight)
        if self.step_index >= len(self.steps):
            return SendNmt("nmt_start", NmtCommand.START)
        if self._in_flight is None:
            self._token += 1
            self._in_flight = self._token
        return WriteStep("sdo", self.steps[self.step_index], self.step_index, self._in_flight)

    # -- events
    def start(self, now: float) -> list[Change]:
        """The gateway starts supervising this node: the boot timeout runs from now."""
        self._arm_boot_timeout(now)
        return []

    def poll(self, now: float) -> list[Change]:
        if (
            self.state is LifecycleState.WAITING
            and self._boot_deadline is not None
            and now > self._boot_deadline
        ):
            self._boot_deadline = None
            waited = now - (self._waiting_since if self._waiting_since is not None else now)
            self.last_error = f"node did not appear (no boot-up) within {self.boot_timeout_s:g} s"
            return [BootTimeout(waited)]
        return []

    def on_bootup(self, now: float) -> list[Change]:
        self.boots += 1
        self.resumable = False
        if self.state is LifecycleState.LISTENING:
            return self._ignore("boot-up")  # the other master configures it
        self._recheck_at = None  # a boot-up is always checked (a device replaced, reflashed)
        out: list[Change] = []
        if self.state is not LifecycleState.BOOTING:
            out.append(self._fire(LifecycleEvent.BOOTUP, "boot-up received"))
        self._preop_pending = False  # SGH10 manual 4.2.1.1: after boot-up it is PRE-OPERATIONAL
        out.append(self._begin_configuring(now, "node is pre-operational after boot-up"))
        return out

    def on_found(self, now: float, device_type: int | None = None) -> list[Change]:
        """The node answers although no boot-up was seen (gateway restarted, cable replugged)."""
        if self.state is not LifecycleState.WAITING or not self.may_probe(now):
            return self._ignore("found")
        if (
            self.expected_device_type is not None
            and device_type is not None
            and device_type != self.expected_device_type
        ):
            self.last_error = (
                f"device type (1000h) is 0x{device_type:08X}, the profile expects "
                f"0x{self.expected_device_type:08X}: not configured"
            )
            delay = self._refuse(now)
            return [WrongDevice(self.expected_device_type, device_type, delay)]
        self._boot_deadline = None
        self._preop_pending, self.resumable = True, False
        self._reset_progress()
        return [self._fire(LifecycleEvent.FOUND, "found running")]

    def on_listen(self, now: float) -> list[Change]:
        """Another master manages the node (a pair's standby): from now on only heard."""
        if self.state is LifecycleState.LISTENING:
            return []
        self._preop_pending = self.resumable = False
        self._reset_progress()
        self._boot_deadline = None
        return [self._fire(LifecycleEvent.LISTEN, "another master manages it: listening")]

    def hold_found(self, now: float) -> bool:
        """A pair's probe answered: True while it waits ``resume_wait_s`` (from the first answer
        since it was lost) to hear the node's state before it counts as found (running:
        resumed; a healed split resolves meanwhile)."""
        if self.hold_until_s is None:
            self.hold_until_s = now + self.resume_wait_s
        return now < self.hold_until_s

    def on_resumed(self, now: float) -> list[Change]:
        """A pair's node waiting is heard OPERATIONAL with no boot-up seen: the pair started it,
        its configuration is intact: taken as it runs, nothing sent. Not a refused device."""
        if self.state is not LifecycleState.WAITING or self.refusals:
            return self._ignore("resumed")
        self.resumable = False
        self._boot_deadline = self.hold_until_s = None
        return [self._fire(LifecycleEvent.RESUMED, "heard operational again, no boot-up: taken as it runs")]

    def on_take_over(self, now: float, adopt: bool, resumable: bool = False) -> list[Change]:
        """A pair's take-over: ``adopt`` (the node was heard started by the other master) takes
        it as it runs, nothing sent; otherwise it is found and configured as usual, unless it
        is ``resumable`` (nothing heard of it yet: heard OPERATIONAL, it resumes as it runs)."""
        if self.state is not LifecycleState.LISTENING:
            return self._ignore("take-over")
        self.last_error = None
        self._reset_progress()
        if adopt:
            self._boot_deadline = None
            return [self._fire(LifecycleEvent.ADOPTED, "adopted as it runs at a take-over")]
        self._arm_boot_timeout(now)
        self.resumable, self.hold_until_s = resumable, None
        return [self._fire(LifecycleEvent.TAKEN_OVER, "taken over: found and configured as usual")]

    def on_lost(self, now: float) -> list[Change]:
        if self.state in (LifecycleState.WAITING, LifecycleState.LISTENING):
            return self._ignore("lost")
        self.resumable, self.hold_until_s = self.state is LifecycleState.OPERATIONAL, None
        self.losses += 1
        self._preop_pending = False
        self._reset_progress()
        self._arm_boot_timeout(now)
        return [self._fire(LifecycleEvent.LOST, "lost (supervision)")]

    def on_nmt_sent(self, now: float) -> list[Change]:
        """The NMT command of the last ``SendNmt`` action went out."""
        if self.state is LifecycleState.BOOTING and self._preop_pending:
            self._preop_pending = False
            return [self._begin_configuring(now, "NMT pre-operational sent")]
        if self.state is LifecycleState.CONFIGURING and self.step_index >= len(self.steps):
            self.configurations += 1
            self.refusals = 0
            self.last_error = None
            started = self._config_started if self._config_started is not None else now
            return [
                self._fire(LifecycleEvent.START_SENT, "configured, NMT start sent"),
                Configured(now - started),
            ]
        return self._ignore("NMT sent")

    def on_step_result(
        self,
        now: float,
        ok: bool,
        abort_code: int | None = None,
        token: int | None = None,
    ) -> list[Change]:
        """Outcome of the last ``WriteStep``; ``abort_code`` None with ``ok`` False = timeout.

        A result for another token than the step in flight (e.g. from before a boot-up) is
        ignored. Without a token the result applies to the step in flight.
        """
        if self.state is not LifecycleState.CONFIGURING or self._in_flight is None:
            return self._ignore("step result")
        if token is not None and token != self._in_flight:
            return self._ignore("step result")
        self._in_flight = None
        index = self.step_index
        step = self.steps[index]
        if ok:
            self.step_index += 1
            self.attempt = 0
            return []
        message = _step_error(step, abort_code)
        if step.optional and abort_code is not None:
            self.step_index += 1
            self.attempt = 0
            return [StepSkipped(index, step, abort_code, message)]
        self.attempt += 1
        self.step_failures += 1
        delay = self.backoff.delay_s(self.attempt)
        self._retry_at = now + delay
        self.last_error = message
        return [StepFailed(index, step, abort_code, self.attempt, delay, message)]

    def on_identity_result(
        self, now: float, value: int | None, abort_code: int | None = None, token: int | None = None
    ) -> list[Change]:
        """Outcome of the last ``ReadIdentity``: the value read, or None with the abort code
        (``IDENTITY_ABSENT``: not compared; another: a refusal) or without (no answer:
        retried with backoff)."""
        if self.state is not LifecycleState.CONFIGURING or self._in_flight is None:
            return self._ignore("identity result")
        if token is not None and token != self._in_flight:
            return self._ignore("identity result")
        self._in_flight = None
        obj, _ = self.expected_identity[self._identity_index]
        if value is None and abort_code is None:
            self.attempt += 1
            delay = self.backoff.delay_s(self.attempt)
            self._retry_at = now + delay
            step = ConfigStep(obj, 0, "uint32", "identity")
            self.last_error = f"{obj} (identity): no SDO answer"
            return [StepFailed(-1, step, None, self.attempt, delay, self.last_error)]
        self.attempt = 0
        out: list[Change] = []
        if value is None and abort_code in IDENTITY_ABSENT:
            self._identity_skipped.add(obj)
            if obj not in self.identity_absent:
                self.identity_absent.add(obj)
                out.append(IdentityNotCompared(obj, abort_code))
        else:
            self._identity_found[obj] = value
        self._identity_index += 1
        if self._identity_index < len(self.expected_identity):
            return out
        compared = [(o, v) for o, v in self.expected_identity if o not in self._identity_skipped]
        if all(self._identity_found.get(o) == v for o, v in compared):
            return out

        def words(values: dict[ObjRef, int | None]) -> str:
            return " ".join(
                f"{IDENTITY_NAMES.get(o.sub, str(o))} {'(unreadable)' if v is None else f'0x{v:X}'}"
                for o, v in values.items()
            )

        found = {o: self._identity_found.get(o) for o, _ in compared}
        self.last_error = (
            f"wrong device: {words(found)}, expected {words(dict(compared))} "
            "(1018h against the EDS): not configured"
        )
        self._reset_progress()
        changed = self._fire(LifecycleEvent.WRONG_IDENTITY, "wrong device (1018h)")
        delay = self._refuse(now)
        vendor = next((v for o, v in compared if o.sub == 1), 0)
        return [*out, changed, WrongDevice(vendor, found.get(ObjRef(0x1018, 1)) or 0, delay)]

    # -- internals
    def _fire(self, event: LifecycleEvent, reason: str) -> StateChanged:
        """The state change ``TRANSITIONS`` defines for ``event`` in the current state."""
        new = TRANSITIONS.get((self.state, event))
        if new is None:
            raise LifecycleError(f"no transition from {self.state} on {event}")
        old, self.state = self.state, new
        return StateChanged(old, new, reason)

    def _ignore(self, event: str) -> list[Change]:
        key = (self.state, event)
        self.ignored[key] = self.ignored.get(key, 0) + 1
        return []

    def _refuse(self, now: float) -> float:
        """A wrong device: no boot timeout report on top (it did appear), and no check again
        before its next boot-up or the recheck delay; returns the delay."""
        self.refusals += 1
        delay = self.recheck.delay_s(self.refusals)
        self._recheck_at = now + delay
        self._boot_deadline = None
        return delay

    def _reset_progress(self) -> None:
        self._identity_index = 0
        self._identity_found = {}
        self._identity_skipped = set()
        self.step_index = 0
        self.attempt = 0
        self._in_flight = None
        self._retry_at = None

    def _begin_configuring(self, now: float, reason: str) -> StateChanged:
        self._boot_deadline = None
        self._reset_progress()
        self._config_started = now
        return self._fire(LifecycleEvent.CONFIGURE, reason)

    def _arm_boot_timeout(self, now: float) -> None:
        self._waiting_since = now
        self._boot_deadline = now + self.boot_timeout_s
