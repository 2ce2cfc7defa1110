"""The process image: the one source of truth northbound.

Every signal has a value, a source timestamp and a quality (good / stale / bad); every node has
its health (NMT state, supervision, guarding-bit link, last EMCY, data age). The bus side writes
here; Modbus and Zenoh read here and are told of changes through listeners. Values of one PDO are
written together (one tuple assignment), so a reader never sees half an update.

Imports: nothing of bus/, modbus/, zenoh_bridge/ (they import this).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any


class Quality(IntEnum):
    GOOD = 0
    STALE = 1  # last known value, the node is not delivering (lost, stopped, stale age)
    BAD = 2  # never received, or the device said the value is invalid


class NmtState(IntEnum):
    """DS-301 NMT states as carried by heartbeat / node guarding."""

    UNKNOWN = -1
    BOOTUP = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class LinkState(IntEnum):
    """Process-data link by the guarding bit (AP05 manual 5.5.5)."""

    NOT_USED = 0
    OK = 1
    FAULT = 2
    UNKNOWN = 3


@dataclass
class SignalValue:
    """Latest value of one signal. ``value`` is the raw device value (int, float, str, bytes)."""

    name: str
    value: Any = None
    timestamp: float = 0.0  # source timestamp (wall clock, seconds) of the frame
    monotonic: float = 0.0  # receive time, monotonic clock, for data age
    seq: int = 0
    valid: bool = True  # device-side validity (e.g. MSK5000 not referenced)


@dataclass
class EmcyRecord:
    code: int
    register: int
    manufacturer: bytes
    text: str
    timestamp: float


@dataclass
class NodeHealth:
    nmt_state: NmtState = NmtState.UNKNOWN
    lifecycle: str = "waiting"
    alive: bool = False
    supervision: str = "heartbeat"
    loss_count: int = 0
    boot_count: int = 0
    link: LinkState = LinkState.NOT_USED
    link_fault_count: int = 0
    last_emcy: EmcyRecord | None = None
    emcy_count: int = 0
    current_errors: list[int] = field(default_factory=list)
    last_sdo_abort: int = 0
    last_error: str = ""
    last_rx_monotonic: float = 0.0
    pdo_errors: int = 0
    rpdo_sent: int = 0


class NodeImage:
    """Signals and health of one node."""

    __slots__ = ("name", "node_id", "family", "signals", "health", "stale_after_s", "serve_stale")

    def __init__(
        self,
        name: str,
        node_id: int,
        family: str,
        signal_names: list[str],
        stale_after_s: float | None = None,
        serve_stale: bool = False,
    ):
        self.name = name
        self.node_id = node_id
        self.family = family
        self.signals: dict[str, SignalValue] = {n: SignalValue(n) for n in signal_names}
        self.health = NodeHealth()
        self.stale_after_s = stale_after_s
        self.serve_stale = serve_stale

    def operational(self) -> bool:
        h = self.health
        return h.alive and h.nmt_state == NmtState.OPERATIONAL and h.link != LinkState.FAULT

    def quality(self, sig: SignalValue, now_monotonic: float | None = None) -> Quality:
        if sig.seq == 0 or not sig.valid:
            return Quality.BAD
        if not self.operational():
            return Quality.STALE
        if self.stale_after_s is not None:
            now = time.monotonic() if now_monotonic is None else now_monotonic
            if now - sig.monotonic > self.stale_after_s:
                return Quality.STALE
        return Quality.GOOD

    def data_age_s(self, now_monotonic: float | None = None) -> float | None:
        last = self.health.last_rx_monotonic
        if not last:
            return None
        return (time.monotonic() if now_monotonic is None else now_monotonic) - last


#: listener(node, signal names updated, timestamp) — called on the bus reader thread
ValueListener = Callable[[NodeImage, tuple[str, ...], float], None]
#: listener(node, what changed: "health" | "emcy" | "state") — called on the event loop
HealthListener = Callable[[NodeImage, str], None]
#: listener(node, COB-ID, raw bytes) for every PDO received (reader thread) or sent
PdoListener = Callable[[NodeImage, int, bytes], None]


class ProcessImage:
    def __init__(self) -> None:
        self.nodes: dict[str, NodeImage] = {}
        self.by_id: dict[int, NodeImage] = {}
        self.value_listeners: list[ValueListener] = []
        self.health_listeners: list[HealthListener] = []
        self.pdo_listeners: list[PdoListener] = []  # raw PDO bytes (e.g. zenoh raw_pdo)
        self.started_monotonic = time.monotonic()
        self.bus_state = "down"
        self.counters: dict[str, int] = {
            "frames_in": 0,
            "frames_out": 0,
            "decode_errors": 0,
            "unknown_cob_id": 0,
            "bus_errors": 0,
        }

    def add_node(self, node: NodeImage) -> None:
        self.nodes[node.name] = node
        self.by_id[node.node_id] = node

    def update(
        self, node: NodeImage, names: tuple[str, ...], values: tuple[Any, ...], ts: float
    ) -> None:
        """Write the values of one PDO (hot path) and tell the value listeners."""
        mono = time.monotonic()
        sigs = node.signals
        for name, value in zip(names, values, strict=False):
            s = sigs[name]
            s.value = value
            s.timestamp = ts
            s.monotonic = mono
            s.seq += 1
        node.health.last_rx_monotonic = mono
        for listener in self.value_listeners:
            listener(node, names, ts)

    def set_valid(self, node: NodeImage, name: str, valid: bool) -> None:
        node.signals[name].valid = valid

    def health_changed(self, node: NodeImage, what: str = "health") -> None:
        for listener in self.health_listeners:
            listener(node, what)
