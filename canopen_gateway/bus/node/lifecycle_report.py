"""What each change a node's lifecycle reports (``bus/node/lifecycle.py``: ``StateChanged``,
``StepFailed``, ``StepSkipped``, ``BootTimeout``, ``WrongDevice``, ``IdentityNotCompared``,
``Configured``) means for the node, as a ``Report`` the node applies (``Node``, in
``bus/node/node.py``): the fields of its health it sets (``lifecycle``, ``last_error``,
``last_sdo_abort``), its log line (``Note``), the new lifecycle state (the state guarding
expects follows it), when a failed boot step is retried, and on ``Configured`` (NMT start
sent) that values are fresh from now on and the features' ``on_configured`` runs. A wrong
device's line is rate-limited by its kind (a device in a boot loop); the recheck delay it names
bounds the rest.

Pure: changes in, reports out; it writes nothing, no I/O and no clock.

Imports: bus.events, bus.node.lifecycle, canopen_gateway.canopen.cia301, logging.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

from canopen_gateway.bus.events import Note
from canopen_gateway.bus.node.lifecycle import (
    IDENTITY_NAMES,
    BootTimeout,
    Change,
    Configured,
    IdentityNotCompared,
    LifecycleState,
    StateChanged,
    StepFailed,
    StepSkipped,
    WrongDevice,
)
from canopen_gateway.canopen.cia301 import abort_text


@dataclass(frozen=True)
class Report:
    """What one lifecycle change means for the node (None: that part does not change)."""

    note: Note
    #: the new lifecycle state: the health's ``lifecycle``, and what guarding expects
    state: LifecycleState | None = None
    last_error: str | None = None
    last_sdo_abort: int | None = None
    #: a boot step failed: nothing is retried before this instant
    wait_until_s: float | None = None
    #: NMT start sent: values received from now on are fresh, the features' ``on_configured``
    configured: bool = False


def lifecycle_reports(
    changes: Sequence[Change], name: str, node_id: int, last_error: str | None, now: float
) -> list[Report]:
    """The reports of the changes, in their order (``last_error``: the lifecycle's)."""
    return [_report(ch, name, node_id, last_error, now) for ch in changes]


def _report(ch: Change, name: str, node_id: int, last_error: str | None, now: float) -> Report:
    if isinstance(ch, StateChanged):
        note = Note(logging.INFO, f"node {name}: {ch.old} -> {ch.new} ({ch.reason})")
        return Report(note, state=ch.new)
    if isinstance(ch, StepFailed):
        text = f"node {name}: boot step {ch.index} failed: {ch.message}; retry {ch.attempt} in {ch.retry_in_s:.1f} s"  # fmt: skip
        return Report(
            Note(logging.WARNING, text),
            last_error=ch.message,
            last_sdo_abort=ch.abort_code,
            wait_until_s=now + ch.retry_in_s,
        )
    if isinstance(ch, StepSkipped):
        return Report(Note(logging.INFO, f"node {name}: optional boot step skipped: {ch.message}"))
    if isinstance(ch, BootTimeout):
        error = last_error or "no boot-up"
        return Report(Note(logging.WARNING, f"node {name} (id {node_id}): {error}"), last_error=error)
    if isinstance(ch, WrongDevice):
        error = last_error or "wrong device type"
        text = f"node {name} (id {node_id}): {error}; checked again at its next boot-up or in {ch.recheck_in_s:g} s"  # fmt: skip
        return Report(Note(logging.ERROR, text, ("wrong_device", name)), last_error=error)
    if isinstance(ch, IdentityNotCompared):
        obj, code = ch.object, ch.abort_code
        what = IDENTITY_NAMES.get(obj.sub, "identity")
        text = f"node {name}: {obj} ({what}) not compared: the device says 0x{code:08X} ({abort_text(code)})"  # fmt: skip
        return Report(Note(logging.INFO, text))
    assert isinstance(ch, Configured)
    text = f"node {name} (id {node_id}) configured in {ch.duration_s * 1000:.0f} ms and started"
    return Report(Note(logging.INFO, text), last_error="", configured=True)
