"""What the lifecycle of a node speaks in (``bus/node/lifecycle.py``): its states, the
actions it asks the driver for, and the changes it reports; what node guarding expects in each
state (``GUARD_EXPECTS``, told to the supervision). Plain values, no behaviour.

Imports: canopen_gateway.device.boot_steps (the step type), canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref,
canopen_gateway.canopen.states and the standard library.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Literal, NamedTuple

from canopen_gateway.canopen.cia301 import SDO_ABORT_NO_OBJECT, SDO_ABORT_NO_SUBINDEX
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.device.boot_steps import ConfigStep


class LifecycleState(StrEnum):
    WAITING = "waiting"  # not seen yet, or lost: waiting for a boot-up / to be found
    BOOTING = "booting"  # seen; an NMT command must go out before configuring
    CONFIGURING = "configuring"  # applying the SDO steps
    OPERATIONAL = "operational"  # configured and NMT start sent
    #: another master manages the node (a pair's standby; a commissioning tool beside a
    #: running master): it is only heard, nothing of its lifecycle acts
    LISTENING = "listening"

    @property
    def guard_expects(self) -> NmtState | None:
        """What a node-guarding answer must report in this state (``GUARD_EXPECTS``)."""
        return GUARD_EXPECTS[self]

    @property
    def answers_configuration(self) -> bool:
        """The node answers its configuration now: its SDO answers are signs of life."""
        return self in (LifecycleState.BOOTING, LifecycleState.CONFIGURING)


#: What a node-guarding answer must report in each lifecycle state. None = any valid state.
#: The supervision (``bus.error_control.node_supervision``) is told it at each change.
GUARD_EXPECTS: dict[LifecycleState, NmtState | None] = {
    LifecycleState.WAITING: None,  # not configured by us yet: whatever it reports
    LifecycleState.BOOTING: None,  # found running: NMT pre-operational is on its way
    LifecycleState.CONFIGURING: NmtState.PRE_OPERATIONAL,  # SGH10 manual 4.2.1.1
    LifecycleState.OPERATIONAL: NmtState.OPERATIONAL,  # after our NMT start
    LifecycleState.LISTENING: None,  # another master's: what it commands (NMT_EXPECTS) if heard
}

# -- actions (what the driver must do); NamedTuples so ``action[0]`` is the kind


class Wait(NamedTuple):
    """Nothing to do for ``seconds`` (a retry is scheduled)."""

    kind: Literal["wait"]
    seconds: float


class WriteStep(NamedTuple):
    """Download ``step`` (SDO) and report with ``on_step_result(..., token=token)``."""

    kind: Literal["sdo"]
    step: ConfigStep
    index: int
    token: int


class SendNmt(NamedTuple):
    """Send NMT ``command`` to the node (SGH10 manual 4.2.1.2 table 3), then ``on_nmt_sent``."""

    kind: Literal["nmt_preop", "nmt_start"]
    command: int


class ReadIdentity(NamedTuple):
    """Upload ``object`` (1018h:01/02/04) and report with ``on_identity_result``."""

    kind: Literal["identity"]
    object: ObjRef
    token: int


Action = Wait | WriteStep | SendNmt | ReadIdentity

#: CiA 301 7.5.2.20 identity object 1018h: the sub-indices compared, and their words.
IDENTITY_NAMES = {0x01: "vendor", 0x02: "product", 0x03: "revision", 0x04: "serial"}
#: CiA 301 table 22: an identity read answered with these aborts is not compared (only
#: 1018h:01 is mandatory; a device may lack 02h..04h): the device holds no such number
IDENTITY_ABSENT = (SDO_ABORT_NO_OBJECT, SDO_ABORT_NO_SUBINDEX)


# -- changes (what happened)


@dataclass(frozen=True)
class StateChanged:
    old: LifecycleState
    new: LifecycleState
    reason: str


@dataclass(frozen=True)
class StepFailed:
    """A configuration step failed; it is retried after ``retry_in_s``."""

    index: int
    step: ConfigStep
    abort_code: int | None  # None: no answer (timeout) or the bus refused to send
    attempt: int
    retry_in_s: float
    message: str


@dataclass(frozen=True)
class StepSkipped:
    """An optional step was refused by the device and skipped."""

    index: int
    step: ConfigStep
    abort_code: int
    message: str


@dataclass(frozen=True)
class BootTimeout:
    """The node did not appear within the boot timeout (reported once per waiting period)."""

    waited_s: float


@dataclass(frozen=True)
class WrongDevice:
    """The node holds another device type (1000h) or identity (1018h) than the file says: it
    is not configured, and checked again at its next boot-up or in ``recheck_in_s``."""

    expected: int
    found: int
    recheck_in_s: float


@dataclass(frozen=True)
class IdentityNotCompared:
    """An identity object the device says it does not have (``IDENTITY_ABSENT``): not compared.
    Reported the first time only (the device says the same at every boot)."""

    object: ObjRef
    abort_code: int


@dataclass(frozen=True)
class Configured:
    """All steps done and NMT start sent."""

    duration_s: float


Change = (
    StateChanged | StepFailed | StepSkipped | BootTimeout | WrongDevice | IdentityNotCompared
    | Configured
)  # fmt: skip
