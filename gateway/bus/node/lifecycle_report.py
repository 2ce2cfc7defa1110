"""How a node takes what its lifecycle reports (``bus/node/lifecycle.py``): each change
(``StateChanged``, ``StepFailed``, ``StepSkipped``, ``BootTimeout``, ``WrongDevice``,
``IdentityNotCompared``, ``Configured``) sets the fields of the node's health it speaks of (``lifecycle``,
``last_error``, ``last_sdo_abort``, ``fresh_since``), becomes a log line (``Note``), tells the
supervision what guarding expects in the new state, and on ``Configured`` (NMT start sent) makes
values fresh from now on and calls the features' ``on_configured``. A wrong device's line is
rate-limited by its kind (a device in a boot loop); the recheck delay it names bounds the rest.

A module-level function taking the ``Node`` (``bus/node/node.py``); like it, no I/O and no
clock.

Imports: bus.node.events, bus.node.lifecycle, gateway.cia301, gateway.states, logging;
bus.node.node for types only.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from gateway.bus.node.events import HealthChanged, Note, Output
from gateway.bus.node.lifecycle import (
    IDENTITY_NAMES,
    BootTimeout,
    Configured,
    IdentityNotCompared,
    StateChanged,
    StepFailed,
    StepSkipped,
    WrongDevice,
)
from gateway.cia301 import abort_text
from gateway.states import NmtState

if TYPE_CHECKING:
    from gateway.bus.node.node import Node


def take_lifecycle_changes(node: Node, changes: list[Any], now: float) -> list[Output]:
    """Each change the lifecycle reported: the health fields it sets, its log line, what
    guarding expects now, and on ``Configured`` the features' ``on_configured``."""
    h = node.health
    out: list[Output] = []
    for ch in changes:
        if isinstance(ch, StateChanged):
            h.lifecycle = str(ch.new)
            out.append(
                Note(logging.INFO, f"node {node.name}: {ch.old} -> {ch.new} ({ch.reason})")
            )
            node.supervision.on_lifecycle(ch.new)
        elif isinstance(ch, StepFailed):
            h.last_error = ch.message
            if ch.abort_code is not None:
                h.last_sdo_abort = ch.abort_code
            node._wait_until = now + ch.retry_in_s
            out.append(
                Note(
                    logging.WARNING,
                    f"node {node.name}: boot step {ch.index} failed: {ch.message}; retry {ch.attempt} in {ch.retry_in_s:.1f} s",
                )
            )
        elif isinstance(ch, StepSkipped):
            out.append(
                Note(
                    logging.INFO, f"node {node.name}: optional boot step skipped: {ch.message}"
                )
            )
        elif isinstance(ch, BootTimeout):
            h.last_error = node.lifecycle.last_error or "no boot-up"
            out.append(
                Note(logging.WARNING, f"node {node.name} (id {node.node_id}): {h.last_error}")
            )
        elif isinstance(ch, WrongDevice):
            h.last_error = node.lifecycle.last_error or "wrong device type"
            text = f"node {node.name} (id {node.node_id}): {h.last_error}; checked again at its next boot-up or in {ch.recheck_in_s:g} s"  # fmt: skip
            out.append(Note(logging.ERROR, text, ("wrong_device", node.name)))
        elif isinstance(ch, IdentityNotCompared):
            obj, code = ch.object, ch.abort_code
            what = IDENTITY_NAMES.get(obj.sub, "identity")
            out.append(
                Note(
                    logging.INFO,
                    f"node {node.name}: {obj} ({what}) not compared: the device says "
                    f"0x{code:08X} ({abort_text(code)})",
                )
            )
        elif isinstance(ch, Configured):
            h.last_error = ""
            h.fresh_since = now  # values are good again when received from now on
            out.append(
                Note(
                    logging.INFO,
                    f"node {node.name} (id {node.node_id}) configured in {ch.duration_s * 1000:.0f} ms and started",
                )
            )
            out += node._set_nmt_expected(NmtState.OPERATIONAL)
            for f in node.features:
                out += f.on_configured(node, now)
    if changes:
        out.append(HealthChanged("state"))
    return out
