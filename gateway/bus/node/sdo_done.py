"""What a finished SDO transfer of a node's own purposes means, as a table keyed by the
purpose (``SDO_DONE``): ``boot`` (a boot step's result to the lifecycle), ``probe`` (1000h of a
node that was already running: found, or a wrong device type), ``identity`` (1018h against the
expected identity) and ``user`` (a client's transfer: ``SdoDone``, then the features that watch
clients' writes). A feature's own purposes are the feature's (``NodeFeature.sdo_done``).

Module-level functions taking the ``Node`` (``bus/node/node.py``), which calls them from
``_sdo_finished``; like it, no I/O and no clock.

Imports: bus.node.events, bus.node.lifecycle (LifecycleState), logging; bus.node.node,
bus.sdo.channel and bus.sdo.client for types only.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from gateway.bus.node.events import Note, Output, SdoDone
from gateway.bus.node.lifecycle import LifecycleState

if TYPE_CHECKING:
    from gateway.bus.node.node import Node
    from gateway.bus.sdo.channel import SdoJob
    from gateway.bus.sdo.client import SdoTransfer


def boot_done(node: Node, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
    ok = tr.result is not None
    code = tr.abort_code if tr.aborted_by_server else None
    return node._lifecycle_changes(
        node.lifecycle.on_step_result(now, ok, code, token=job.arg.token), now
    )


def probe_done(node: Node, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
    node._last_probe_end_s = now
    if tr.result is None or node.lifecycle.state is not LifecycleState.WAITING:
        return []
    device_type = int.from_bytes(tr.result[:4].ljust(4, b"\0"), "little")
    out: list[Output] = [
        Note(logging.INFO, f"node {node.name} (id {node.node_id}) found running")
    ]
    out += node._lifecycle_changes(node.lifecycle.on_found(now, device_type), now)
    if node.lifecycle.state is LifecycleState.BOOTING:  # not a wrong device type
        node.supervision.on_found(now)
        if not node.supervision.guard_lost:
            out += node._set_alive(True, now)
    return out


def identity_done(node: Node, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
    value = int.from_bytes(tr.result[:4].ljust(4, b"\0"), "little") if tr.result is not None else None
    code = None if value is not None or tr.timed_out else (tr.abort_code or 0x08000000)
    changes = node.lifecycle.on_identity_result(now, value, code, token=job.arg.token)
    return node._lifecycle_changes(changes, now)


def user_done(node: Node, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
    out: list[Output] = [
        SdoDone(job.token, tr.result, tr.abort_code, tr.timed_out, tr.aborted_by_server)
    ]
    for f in node.features:
        out += f.on_user_sdo(node, job, now)
    return out


#: what a finished transfer means, by its purpose (a feature's own purposes: the feature's
#: ``sdo_done``)
SDO_DONE: dict[str, Callable[[Node, SdoJob, SdoTransfer, float], list[Output]]] = {
    "boot": boot_done,
    "probe": probe_done,
    "identity": identity_done,
    "user": user_done,
}
