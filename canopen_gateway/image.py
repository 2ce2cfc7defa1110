"""The process image: the one source of truth northbound.

Every signal has a value, a source timestamp and a quality (good / stale / bad); every node has
its health (NMT state, supervision, guarding-bit link, last EMCY, data age). The bus side writes
here; Modbus and Zenoh read here and are told of changes through listeners. Values of one PDO are
written together (one immutable record, one assignment), so a reader never sees half an update.

Imports: canopen_gateway.canopen.states only; nothing of bus/, modbus/, zenoh_bridge/ (they import this).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, NamedTuple

from canopen_gateway.canopen.states import LinkState, NmtState


class Quality(IntEnum):
    GOOD = 0
    STALE = 1  # last known value: the node is not delivering (lost, rebooted, stopped, aged)
    BAD = 2  # never received, or the device said the value is invalid


class SignalValue(NamedTuple):
    """Latest value of one signal, immutable: a reader holds one frame's value or another's.

    ``value`` is the raw device value (int, float, str, bytes)."""

    name: str
    value: Any = None
    timestamp: float = 0.0  # source timestamp (wall clock, seconds) of the frame
    # receive time on the bus clock (monotonic; an SDO read: its request's), for data age
    # and freshness
    monotonic: float = 0.0
    seq: int = 0  # values received for this signal (0 = never)


@dataclass
class EmcyRecord:
    code: int
    register: int
    manufacturer: bytes
    text: str
    timestamp: float


@dataclass
class NodeHealth:
    """A node's health. Written by the node's owner only (``bus.node.node.Node``, on the event
    loop); read by everyone."""

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
    emcy_errors: int = 0  # EMCY frames too short to decode
    emcy_history: tuple[Any, ...] = ()
    current_errors: list[int] = field(default_factory=list)
    last_sdo_abort: int = 0
    last_error: str = ""
    rpdo_sent: int = 0
    # Values received before this instant (monotonic) are stale; None = none is good (the node
    # booted or was lost and has not been started by the gateway since).
    fresh_since: float | None = None
    invalid_signals: frozenset[str] = frozenset()  # flagged invalid (MSK5000 not referenced)
    # "safe" from the output watchdog's write of the safe values until the next client write
    outputs: str = "normal"


class RxCell:
    """One thread's share of a node's receive counters (written by that thread only)."""

    __slots__ = ("pdo_too_short", "pdo_too_long", "last_rx_monotonic")

    def __init__(self) -> None:
        self.pdo_too_short = 0  # PDOs shorter than their mapping (not decoded)
        self.pdo_too_long = 0  # PDOs longer than their mapping (mapped bytes decoded)
        self.last_rx_monotonic = 0.0


class RxCounters:
    """A node's receive counters, exact under threads: each writing thread writes its own
    ``RxCell`` (the reader thread for TPDOs, the event loop for values read by SDO); readers
    sum the counts and take the latest receive time."""

    __slots__ = ("_cells", "_local")

    def __init__(self) -> None:
        self._cells: list[RxCell] = []
        self._local = threading.local()

    def new_cell(self) -> RxCell:
        """A cell for one thread only (e.g. made for the reader thread when its handler is
        built); never written by another thread."""
        cell = RxCell()
        self._cells.append(cell)  # one append: a reader sums the old list or the new one
        return cell

    def cell(self) -> RxCell:
        """The calling thread's own cell."""
        cell: RxCell | None = getattr(self._local, "cell", None)
        if cell is None:
            cell = self._local.cell = self.new_cell()
        return cell

    @property
    def pdo_too_short(self) -> int:
        return sum(c.pdo_too_short for c in self._cells)

    @property
    def pdo_too_long(self) -> int:
        return sum(c.pdo_too_long for c in self._cells)

    @property
    def last_rx_monotonic(self) -> float:
        return max((c.last_rx_monotonic for c in self._cells), default=0.0)


class SentOutputs(NamedTuple):
    """The node's output image as the gateway last set it: the values each RPDO carries (as
    last sent, or as set for its next frame when a write changed a signal that RPDO shares
    with the one sent). One immutable record, written by ``bus.node.node.Node`` in one assignment
    on the event loop; readers (the command service for Modbus, Zenoh and the web console)
    see one write or the next, never a mix."""

    rpdos: Mapping[int, tuple[Any, ...]]  # RPDO number -> values in mapping order
    timestamp: float = 0.0  # wall clock of the last write (seconds since the epoch)
    monotonic: float = 0.0  # bus-clock time of the last write
    seq: int = 0  # writes so far (0 = nothing written yet)


_new = tuple.__new__  # a NamedTuple without its Python-level __new__ (hot path)

#: One frame's values: (values in mapping order, source timestamp, receive time, frames so far)
Record = tuple[tuple[Any, ...], float, float, int]


class SignalView(Mapping[str, SignalValue]):
    """``node.signals``: signal name -> its latest ``SignalValue``, computed from the records.

    A signal may live in several records (SGH10 TPDO1 and TPDO2 carry the same values; a value
    read by SDO): the one valid latest wins (its ``monotonic``: a frame's receive time, an SDO
    read's request time; ``ProcessImage.update``), and ``seq`` counts all of them."""

    __slots__ = ("_records", "_where")

    def __init__(self, records: dict[Any, Record], where: dict[str, tuple[tuple[Any, int], ...]]):
        self._records = records
        self._where = where

    def __getitem__(self, name: str) -> SignalValue:
        slots = self._where[name]
        records = self._records
        if len(slots) == 1:  # the common case: the signal is in one PDO
            key, index = slots[0]
            r = records.get(key)
            if r is None:
                return SignalValue(name)
            return _new(SignalValue, (name, r[0][index], r[1], r[2], r[3]))
        best: Record | None = None
        index = 0
        seq = 0
        for key, i in slots:
            r = records.get(key)
            if r is not None:
                seq += r[3]
                if best is None or r[2] >= best[2]:
                    best, index = r, i
        if best is None:
            return SignalValue(name)
        return _new(SignalValue, (name, best[0][index], best[1], best[2], seq))

    def __iter__(self) -> Iterator[str]:
        return iter(self._where)

    def __len__(self) -> int:
        return len(self._where)

    def __contains__(self, name: object) -> bool:
        return name in self._where


class NodeImage:
    """Signals, outputs and health of one node.

    Values are kept as one immutable record per PDO (``records``, keyed by the tuple of the
    signal names it carries): the reader thread puts a whole frame in with one assignment, so a
    reader sees one frame or the other, never a mix. ``signals`` is the per-signal view of the
    records; ``snapshot()`` is a consistent view for a request that reads several signals.
    Which records feed which signal (``where``) is bound when the node is built (``bind``),
    before any thread writes a record: a write never changes it.

    ``outputs`` is the output image (``SentOutputs``), its own section: the values last set
    for the node's RPDOs, replaced whole by the node's owner on the event loop.
    """

    __slots__ = (
        "name", "node_id", "family", "records", "where", "signals", "health", "rx",
        "stale_after_s", "serve_stale", "outputs", "output_slots", "network",
    )  # fmt: skip

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
        self.records: dict[Any, Record] = {}
        self.where: dict[str, tuple[tuple[Any, int], ...]] = {n: () for n in signal_names}
        self.signals = SignalView(self.records, self.where)
        self.health = NodeHealth()
        self.rx = RxCounters()
        self.stale_after_s = stale_after_s
        self.serve_stale = serve_stale
        self.outputs = SentOutputs({})
        #: signal -> (RPDO number, index in its values) of every RPDO carrying it, in order
        self.output_slots: dict[str, tuple[tuple[int, int], ...]] = {}
        #: the CAN network the node is on (set once, when its network is built)
        self.network = "default"

    def bind(self, names: tuple[str, ...]) -> None:
        """Make the record keyed ``names`` a source of those signals. Called while the node
        is built (``bus.node.parts.build_node``: every TPDO, every value read by SDO), before the
        reader thread runs; ``put`` never binds."""
        where = self.where
        for i, n in enumerate(names):
            slots = where.get(n, ())
            if (names, i) not in slots:
                where[n] = (*slots, (names, i))  # one assignment: readers see old or new

    def is_bound(self, names: tuple[str, ...]) -> bool:
        """Is the record keyed ``names`` a source of each of its signals?"""
        where = self.where
        return all((names, i) in where.get(n, ()) for i, n in enumerate(names))

    def bind_output(self, number: int, names: tuple[str, ...]) -> None:
        """RPDO ``number`` carries ``names`` (while the node is built, like ``bind``)."""
        slots = self.output_slots
        for i, n in enumerate(names):
            slots[n] = (*slots.get(n, ()), (number, i))

    def put(self, names: tuple[str, ...], values: tuple[Any, ...], ts: float, mono: float) -> None:
        """Values of one frame (or of one SDO read), in one assignment. The key is bound."""
        records = self.records
        old = records.get(names)
        records[names] = (values, ts, mono, old[3] + 1 if old is not None else 1)

    def snapshot(self) -> SignalView:
        return SignalView(dict(self.records), self.where)

    def set_value(self, sv: SignalValue) -> None:
        """Put one signal's value as given (tests and tools, on one thread, nothing running)."""
        key = (sv.name,)
        self.bind(key)
        self.records[key] = ((sv.value,), sv.timestamp, sv.monotonic, sv.seq)

    def output(self, name: str, pdo: int | None = None, sent: SentOutputs | None = None) -> Any:
        """The value of output ``name`` in RPDO ``pdo`` (default: the last RPDO carrying it)
        in ``sent`` (default: the current output image). KeyError when no RPDO carries it."""
        slots = self.output_slots[name]
        number, index = next((s for s in slots if s[0] == pdo), slots[-1])
        values = (self.outputs if sent is None else sent).rpdos.get(number)
        return None if values is None else values[index]

    def operational(self) -> bool:
        h = self.health
        return h.alive and h.nmt_state == NmtState.OPERATIONAL and h.link != LinkState.FAULT

    def usable(self) -> bool:
        """Values usable: operational and its guarding-bit link (if any) confirmed OK. The
        Zenoh liveliness token ``alive/<node>`` follows this."""
        return self.operational() and self.health.link in (LinkState.OK, LinkState.NOT_USED)

    def is_valid(self, name: str) -> bool:
        return name not in self.health.invalid_signals

    def quality(self, sig: SignalValue, now_monotonic: float | None = None) -> Quality:
        h = self.health
        if sig.seq == 0 or (h.invalid_signals and sig.name in h.invalid_signals):
            return Quality.BAD
        fresh = h.fresh_since
        if (
            fresh is None
            or sig.monotonic < fresh
            or not h.alive
            or h.nmt_state is not NmtState.OPERATIONAL
            or h.link is LinkState.FAULT
        ):
            return Quality.STALE
        if self.stale_after_s is not None:
            now = time.monotonic() if now_monotonic is None else now_monotonic
            if now - sig.monotonic > self.stale_after_s:
                return Quality.STALE
        return Quality.GOOD

    def data_age_s(self, now_monotonic: float | None = None) -> float | None:
        last = self.rx.last_rx_monotonic
        if not last:
            return None
        return (time.monotonic() if now_monotonic is None else now_monotonic) - last


#: listener(node, signal names updated, timestamp) — called on the bus reader thread (TPDOs) or
#: the event loop (values read by SDO, outputs written)
ValueListener = Callable[[NodeImage, tuple[str, ...], float], None]
#: listener(node, what changed: "health" | "emcy" | "state") — called on the event loop
HealthListener = Callable[[NodeImage, str], None]
#: listener(node, COB-ID, raw bytes) for every PDO received (reader thread) or sent
PdoListener = Callable[[NodeImage, int, bytes], None]


class Counters:
    """Event counters, exact under threads: each thread counts in its own ``CounterSet``
    (``image.counter_set()``) and readers sum them."""

    NAMES = ("frames_in", "frames_out", "decode_errors", "unknown_cob_id", "bus_errors",
             "pdo_too_long", "emcy_errors", "bursts")  # fmt: skip

    def __init__(self) -> None:
        self._sets: list[dict[str, int]] = []

    def counter_set(self) -> dict[str, int]:
        """A dict of counters for one thread only (never shared)."""
        d = dict.fromkeys(self.NAMES, 0)
        self._sets.append(d)
        return d

    def __getitem__(self, name: str) -> int:
        return sum(d.get(name, 0) for d in list(self._sets))

    def __contains__(self, name: object) -> bool:
        return name in self.NAMES

    def snapshot(self) -> dict[str, int]:
        return {n: self[n] for n in self.NAMES}


class ProcessImage:
    def __init__(self) -> None:
        self.nodes: dict[str, NodeImage] = {}
        self.by_id: dict[int, NodeImage] = {}
        self.value_listeners: list[ValueListener] = []
        self.health_listeners: list[HealthListener] = []
        self.pdo_listeners: list[PdoListener] = []  # raw PDO bytes (e.g. zenoh raw_pdo)
        #: called by a writer after a batch of ``update`` calls (the reader thread once per
        #: burst of frames; the event loop after values read by SDO): a listener that hands
        #: work to another thread wakes it here, once per batch instead of once per value
        self.batch_listeners: list[Callable[[], None]] = []
        self.started_monotonic = time.monotonic()
        #: each CAN network's bus state (``ok``, ``error``, ``down``), written by its driver's
        #: threads (one key each, one assignment)
        self.bus_states: dict[str, str] = {}
        self.counters = Counters()
        self._loop_counters = self.counters.counter_set()  # counted on the event loop

    @property
    def bus_state(self) -> str:
        """The worst bus state of the networks: ``down`` if one is down (or none opened yet),
        else ``error`` if one is in error, else ``ok``."""
        states = list(self.bus_states.values())
        if not states or "down" in states:
            return "down"
        return "error" if "error" in states else "ok"

    def set_bus_state(self, network: str, state: str) -> None:
        """Network ``network``'s bus is now ``state`` (its driver, on the thread that saw it)."""
        self.bus_states[network] = state

    def count(self, name: str, n: int = 1) -> None:
        """Count on the event loop (other threads use their own ``counters.counter_set()``)."""
        self._loop_counters[name] = self._loop_counters.get(name, 0) + n

    def add_node(self, node: NodeImage) -> None:
        self.nodes[node.name] = node
        self.by_id[node.node_id] = node

    def update(
        self,
        node: NodeImage,
        names: tuple[str, ...],
        values: tuple[Any, ...],
        ts: float,
        rx: RxCell | None = None,
        mono: float | None = None,
    ) -> None:
        """Write the values of one PDO (hot path: one record, one assignment) and tell the value
        listeners. ``names`` is a bound key (``NodeImage.bind``); ``rx`` is the calling
        thread's cell of the node's counters (default: looked up). Each record has one writer:
        a TPDO's is the reader thread, a value read by SDO's is the event loop.

        ``mono`` is when the values were valid, on the bus clock (monotonic) that
        ``fresh_since`` is on: a TPDO's receive time, a value read by SDO the time its
        request went out (default: now). The freshness of a value and which record of a
        signal is the latest are decided by it, not by when the writer got to it."""
        if mono is None:
            mono = time.monotonic()
        node.put(names, values, ts, mono)
        (rx or node.rx.cell()).last_rx_monotonic = mono
        for listener in self.value_listeners:
            listener(node, names, ts)

    def outputs_written(self, node: NodeImage, names: tuple[str, ...]) -> None:
        """The node's outputs ``names`` were written (event loop, after ``Node`` replaced
        ``node.outputs``): the value listeners hear of it as of new values (the web console's
        live pages show the outputs)."""
        ts = node.outputs.timestamp
        for listener in self.value_listeners:
            listener(node, names, ts)

    def end_batch(self) -> None:
        """A writer finished a batch of updates (see ``batch_listeners``)."""
        for listener in self.batch_listeners:
            listener()

    def health_changed(self, node: NodeImage, what: str = "health") -> None:
        for listener in self.health_listeners:
            listener(node, what)
