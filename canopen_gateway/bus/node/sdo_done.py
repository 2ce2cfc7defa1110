"""What a finished SDO transfer of a node's own purposes means, as a table keyed by the
purpose (``SDO_DONE``): ``boot`` (a boot step's result to the lifecycle), ``probe`` (1000h of a
node that was already running: found, or a wrong device type), ``identity`` (1018h against the
expected identity) and ``user`` (a client's transfer: ``SdoDone``, then the features that watch
clients' writes). A feature's own purposes are the feature's (``NodeFeature.sdo_done``).

Each entry tells its node's lifecycle the result and returns an ``SdoOutcome``: the outputs,
the lifecycle's changes and what else the node (``bus/node/node.py``, ``_sdo_finished``) must
do; the node applies it. Nothing here writes the node; no I/O and no clock.

Imports: bus.events, bus.node.lifecycle, logging; bus.sdo.channel and bus.sdo.client for
types only.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from canopen_gateway.bus.events import Note, Output, SdoDone
from canopen_gateway.bus.node.lifecycle import Change, LifecycleState, NodeLifecycle

if TYPE_CHECKING:
    from canopen_gateway.bus.sdo.channel import SdoJob
    from canopen_gateway.bus.sdo.client import SdoTransfer


class DoneContext(Protocol):
    """What the meaning of a finished transfer reads of its node (``Node`` is one)."""

    @property
    def name(self) -> str: ...

    @property
    def node_id(self) -> int: ...

    @property
    def lifecycle(self) -> NodeLifecycle: ...

    @property
    def resumes(self) -> bool: ...  # a pair's member: a running node found is taken as it runs


#: while a pair's node found by a probe waits to be heard, it is probed again this often (the
#: answers tell the member its bus works: a silent bus at a first start is not a cut cable)
HOLD_PROBE_S = 0.1


@dataclass(frozen=True)
class SdoOutcome:
    """What a finished transfer means for its node, in the order the node applies it."""

    outputs: list[Output] = field(default_factory=list)
    #: what the lifecycle reported (the node's lifecycle report, after ``outputs``)
    changes: list[Change] = field(default_factory=list)
    #: a probe ended now (an unprompted probe waits a while after it)
    probe_ended: bool = False
    #: when to probe again (a pair's node found: once its wait to be heard is over)
    probe_again_s: float | None = None
    #: a probe found the expected device running: supervision restarts, the node is alive
    found: bool = False
    #: a client's transfer: the features that watch clients' writes see it
    user: bool = False


def _u32(data: bytes) -> int:
    return int.from_bytes(data[:4].ljust(4, b"\0"), "little")


def boot_done(node: DoneContext, job: SdoJob, tr: SdoTransfer, now: float) -> SdoOutcome:
    ok = tr.result is not None
    code = tr.abort_code if tr.aborted_by_server else None
    return SdoOutcome(changes=node.lifecycle.on_step_result(now, ok, code, token=job.arg.token))


def probe_done(node: DoneContext, job: SdoJob, tr: SdoTransfer, now: float) -> SdoOutcome:
    lifecycle = node.lifecycle
    if tr.result is None or lifecycle.state is not LifecycleState.WAITING:
        return SdoOutcome(probe_ended=True)
    if node.resumes and lifecycle.hold_found(now):  # a pair's: its state heard first (running: resumed)
        again = min(lifecycle.hold_until_s or now, now + HOLD_PROBE_S)  # its answers: the bus heard
        return SdoOutcome(probe_ended=True, probe_again_s=again)
    note = Note(logging.INFO, f"node {node.name} (id {node.node_id}) found running")
    changes = lifecycle.on_found(now, _u32(tr.result))
    found = lifecycle.state is LifecycleState.BOOTING  # not a wrong device type
    return SdoOutcome([note], changes, probe_ended=True, found=found)


def identity_done(node: DoneContext, job: SdoJob, tr: SdoTransfer, now: float) -> SdoOutcome:
    value = _u32(tr.result) if tr.result is not None else None
    code = None if value is not None or tr.timed_out else (tr.abort_code or 0x08000000)
    return SdoOutcome(
        changes=node.lifecycle.on_identity_result(now, value, code, token=job.arg.token)
    )


def user_done(node: DoneContext, job: SdoJob, tr: SdoTransfer, now: float) -> SdoOutcome:
    done = SdoDone(job.token, tr.result, tr.abort_code, tr.timed_out, tr.aborted_by_server)
    return SdoOutcome([done], user=True)


#: what a finished transfer means, by its purpose (a feature's own purposes: the feature's
#: ``sdo_done``)
SDO_DONE: dict[str, Callable[[DoneContext, SdoJob, SdoTransfer, float], SdoOutcome]] = {
    "boot": boot_done,
    "probe": probe_done,
    "identity": identity_done,
    "user": user_done,
}
