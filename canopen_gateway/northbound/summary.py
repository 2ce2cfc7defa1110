"""One health summary per node, read from the process image once and formatted by each
adapter: Zenoh's ``<node>/state`` payload, the node diagnostics in Modbus input registers and
discrete inputs, the node rows of the web console and ``/healthz``.

A summary is taken at one instant (``now``, monotonic): the data age and the worst process
quality are computed once, so two adapters never disagree on what "operational" or "usable"
means. The words each adapter uses for a state (``QUALITY_TEXT``, the Modbus codes) are theirs.

Imports: image, canopen.states. Nothing of bus/ or of an adapter.
"""

from __future__ import annotations

import time
from collections.abc import Collection
from dataclasses import dataclass, fields
from typing import Any

from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.image import EmcyRecord, NodeHealth, NodeImage, Quality

#: quality as every adapter writes it in text
QUALITY_TEXT = {Quality.GOOD: "good", Quality.STALE: "stale", Quality.BAD: "bad"}


@dataclass(slots=True)
class NodeSummary:
    """A node's health at one instant (see the module docstring). Not frozen: one is made on
    every Modbus read of a node's diagnostics, and a frozen dataclass's ``__init__`` (one
    ``object.__setattr__`` per field) made ``summarize`` cost 10 us instead of 6.6; nothing
    changes a summary once made."""

    name: str
    node_id: int
    nmt_state: NmtState
    alive: bool
    #: alive, OPERATIONAL and the guarding-bit link not in fault
    operational: bool
    #: operational and the link confirmed OK (or not used): the Zenoh liveliness token follows it
    usable: bool
    lifecycle: str
    supervision: str
    link: LinkState
    link_fault_count: int
    loss_count: int
    boot_count: int
    emcy_count: int
    last_emcy: EmcyRecord | None
    current_errors: tuple[int, ...]
    last_sdo_abort: int
    last_error: str
    #: "normal", or "safe" from the output watchdog's write of the safe values
    outputs: str
    #: seconds since the last value received from the node; None: none yet
    data_age_s: float | None
    #: PDOs received shorter or longer than their mapping
    pdo_errors: int
    #: the worst quality of the node's process signals (None when not asked for)
    quality: Quality | None = None

    @property
    def link_ok(self) -> bool:
        return self.link in (LinkState.OK, LinkState.NOT_USED)

    @property
    def presence(self) -> str:
        """"alive", "lost" (seen before) or "not seen"."""
        if self.alive:
            return "alive"
        return "lost" if self.boot_count or self.loss_count else "not seen"


#: the summary's fields that are the node health's own (same name, same type): copied as they are
_HEALTH_TYPES = {h.name: h.type for h in fields(NodeHealth)}
HEALTH_FIELDS = tuple(f.name for f in fields(NodeSummary) if f.type == _HEALTH_TYPES.get(f.name))


def serves_values(node: NodeImage, process: Collection[str]) -> bool:
    """Whether the node serves any process data: signals its TPDOs carry (``process``) or
    outputs its RPDOs carry. A node whose PDOs map nothing serves no value."""
    return bool(process) or bool(node.output_slots)


def worst_quality(node: NodeImage, process: Collection[str], now: float) -> Quality:
    """The worst quality of ``process`` (the signals the node's TPDOs carry) from one snapshot;
    a node with outputs only is good while operational, else stale; a node whose PDOs map
    nothing is bad: it has no value to serve, so no reader may take it as good."""
    if not process:
        if not serves_values(node, process):
            return Quality.BAD
        return Quality.GOOD if node.operational() else Quality.STALE
    snap = node.snapshot()
    return max(node.quality(snap[n], now) for n in process)


def summarize(
    node: NodeImage, now: float | None = None, process: Collection[str] | None = None
) -> NodeSummary:
    """The node's summary at ``now`` (monotonic, default: the current time); with ``process``
    (its process signal names) the worst quality too."""
    now = time.monotonic() if now is None else now
    h = node.health
    rx = node.rx
    return NodeSummary(
        **{name: getattr(h, name) for name in HEALTH_FIELDS},
        name=node.name,
        node_id=node.node_id,
        operational=node.operational(),
        usable=node.usable(),
        current_errors=tuple(h.current_errors),
        data_age_s=node.data_age_s(now),
        pdo_errors=rx.pdo_too_short + rx.pdo_too_long,
        quality=None if process is None else worst_quality(node, process, now),
    )


def health_doc(node: NodeImage) -> dict[str, Any]:
    """A node as ``/healthz`` says it: its network, health and data age."""
    s = summarize(node)
    age = s.data_age_s
    return {
        "node_id": s.node_id,
        "network": node.network,
        "alive": s.alive,
        "operational": s.operational,
        "nmt_state": s.nmt_state.name.lower(),
        "lifecycle": s.lifecycle,
        "link": s.link.name.lower(),
        "data_age_s": None if age is None else round(age, 3),
        "last_error": s.last_error,
        "outputs": s.outputs,
    }
