"""One writer per datum: the races between the CAN reader thread and the event loop, each driven
through the exact interleaving that broke it (a hook runs the other writer at the worst moment),
so the tests are deterministic: no sleeps, no luck.

* the image's record keys are bound when the node is built, never by the first writer;
* the bus clock's state is written in one assignment, so it never jumps back by the idle gap;
* a node's receive counters are per thread, read as their sum and latest time;
* counts made on several threads (Zenoh publications) are per thread, summed when read.
"""

from __future__ import annotations

import sys
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import can
import pytest

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.master import Master
from canopen_gateway.image import NodeImage, ProcessImage, SignalView
from tests.helpers import make_config, resolved

WAIT_S = 5.0
#: SGH10 whose TPDO1 sends on change only and allows no RTR (DS-301 1800h:01 bit 30): after
#: NMT start the gateway reads its values by SDO, so each is in two records (TPDO and SDO read)
WIRE = {
    "name": "wire",
    "node_id": 1,
    "profile": "sgh10",
    "sdo": [{"object": "0x1800:05", "value": 0}, {"object": "0x1800:01", "value": 0x40000181}],
}


def built_master(nodes: list[dict[str, Any]]) -> Master:
    """The master of ``nodes`` built as at start (nothing opened, no thread running)."""
    cfg = make_config(nodes, modbus={"enabled": False}, zenoh={"enabled": False})
    image = ProcessImage()
    return Master(cfg, image, BusDriver(cfg.can.bus_kwargs(), image), nodes=resolved(cfg))


class HookedWhere(dict[str, Any]):
    """``NodeImage.where`` that runs ``hook`` once, the first time ``signal``'s sources are
    looked up with ``get`` (where a writer binding on its first put reads them)."""

    def __init__(self, where: dict[str, Any], signal: str, hook: Callable[[], None]):
        super().__init__(where)
        self.signal, self.hook, self.fired = signal, hook, False

    def get(self, key: str, default: Any = None) -> Any:
        value = super().get(key, default)
        if key == self.signal and not self.fired:
            self.fired = True
            self.hook()  # the other writer runs here, between the read and the write back
        return value


# --------------------------------------------------------------------------- record keys


def test_every_source_of_a_signal_is_bound_when_the_node_is_built() -> None:
    master = built_master([WIRE])
    p = master.nodes["wire"]
    node = p.image
    assert node.records == {}  # nothing received yet
    for codec in p.tpdos:
        assert node.is_bound(codec.names), codec.names
    for r in p.node.refresh_plan:
        for name, _obj, _type in r.objects:
            assert node.is_bound((name,)), name
    tpdo = next(c for c in p.tpdos if "position" in c.names)
    assert node.where["position"] == ((tpdo.names, tpdo.names.index("position")), (("position",), 0))


def test_two_first_writers_of_one_signal_never_lose_a_source() -> None:
    """Right after NMT start the reader thread writes the first TPDO and the event loop the
    first value read by SDO of the same signal: the reader runs exactly between the loop's
    read of the signal's sources and its write back. Before the keys were bound at build
    time, the loop's write dropped the TPDO as a source and the signal froze on the SDO
    value (good for ever where ``stale_after_ms`` is unset)."""
    master = built_master([WIRE])
    p = master.nodes["wire"]
    image, node = master.image, p.image
    tpdo = next(c for c in p.tpdos if "position" in c.names)
    frame = tuple(222 if n == "position" else 0 for n in tpdo.names)

    def reader_writes_a_tpdo() -> None:
        t = threading.Thread(target=image.update, args=(node, tpdo.names, frame, 2.0))
        t.start()
        t.join(WAIT_S)

    node.where = HookedWhere(node.where, "position", reader_writes_a_tpdo)
    node.signals = SignalView(node.records, node.where)
    image.update(node, ("position",), (111,), 1.0)  # the loop: the value read by SDO
    if not node.where.fired:  # the write did not look at the sources: the reader comes after
        reader_writes_a_tpdo()

    assert (("position",), 0) in node.where["position"]
    assert (tpdo.names, tpdo.names.index("position")) in node.where["position"]
    assert node.signals["position"].value == 222  # the later record wins
    assert node.signals["position"].seq == 2  # both records count


# --------------------------------------------------------------------------- bus clock


class Clocks:
    def __init__(self) -> None:
        self.mono = 1000.0
        self.wall = 1_700_000_000.0


class TimedMessage(can.Message):  # type: ignore[misc]
    """A received frame whose timestamp, when the reader first reads it, runs ``on_read``."""

    def __init__(self, msg: can.Message, timestamp: float, on_read: Callable[[], None]):
        self.on_read: Callable[[], None] | None = None
        super().__init__(
            arbitration_id=msg.arbitration_id,
            data=msg.data,
            is_extended_id=msg.is_extended_id,
            timestamp=timestamp,
        )
        self.on_read = on_read

    @property  # type: ignore[override]
    def timestamp(self) -> float:
        hook, self.on_read = self.on_read, None
        if hook is not None:
            hook()
        return self._ts

    @timestamp.setter
    def timestamp(self, value: float) -> None:
        self._ts = value


def test_the_bus_clock_never_jumps_back_by_the_idle_gap_when_a_frame_arrives(
    can_frame: Callable[..., can.Message],
) -> None:
    """The reader was idle for 10 s; a frame arrives. The event loop reads the bus clock
    exactly while the reader takes the frame (when it reads the frame's timestamp): the clock
    must be the monotonic time, not 10 s in the past (which delays a loss by that gap)."""
    c = Clocks()
    channel = f"clock-{uuid.uuid4().hex}"
    d = BusDriver(
        {"interface": "virtual", "channel": channel},
        ProcessImage(),
        mono=lambda: c.mono,
        wall=lambda: c.wall,
    )
    device = can.Bus(interface="virtual", channel=channel)
    seen: list[float] = []
    handled: list[int] = []

    def loop_reads_clock() -> None:
        seen.append(d.bus_clock())

    def after_first_burst() -> None:
        if len(handled) == 1:
            c.mono += 10.0  # an idle gap of 10 s, then the next frame
            c.wall += 10.0
            device.send(can_frame(0x701, "05"))  # heartbeat: operational

    def handle(msg: can.Message) -> None:
        handled.append(msg.arbitration_id)
        if len(handled) == 2:
            d._running.clear()  # two frames are the whole scenario: the reader returns

    d.handlers[0x701] = handle
    d.burst_listeners.append(after_first_burst)
    d.bus = can.Bus(interface="virtual", channel=channel)
    real_recv = d.bus.recv

    def recv(timeout: float | None = None) -> can.Message | None:
        msg = real_recv(timeout=WAIT_S if timeout else 0.0)
        if msg is None:
            return None
        # frames stamped on the fake wall clock; the loop reads the clock during the second
        return TimedMessage(msg, c.wall, loop_reads_clock if handled else lambda: None)

    d.bus.recv = recv  # type: ignore[method-assign]
    try:
        d.clock_state = (True, 0.0)
        device.send(can_frame(0x701, "05"))  # heartbeat: operational
        d._running.set()
        d._run()  # the reader's loop, on this thread, frame by frame
    finally:
        device.shutdown()
        d.bus.shutdown()
    assert handled == [0x701, 0x701]
    assert seen == [c.mono]  # the loop saw the bus clock of now, not of 10 s ago
    assert d.clock_state == (False, c.wall)


def test_a_reopen_waits_its_backoff_on_the_injectable_clock() -> None:
    c = Clocks()
    d = BusDriver(
        {"interface": "virtual", "channel": f"reopen-{uuid.uuid4().hex}"},
        ProcessImage(),
        reopen_backoff_s=30.0,
        mono=lambda: c.mono,
    )
    waits: list[float] = []

    class Closing:
        """close() wakes the backoff; here each wait advances the fake clock instead."""

        def wait(self, timeout: float) -> bool:
            waits.append(timeout)
            c.mono += timeout
            return False

    d._closing = Closing()  # type: ignore[assignment]
    d._running.set()
    try:
        assert d._reopen()  # 30 s of backoff on the fake clock, none on the wall clock
        assert d.state == "ok" and d.bus is not None
        assert sum(waits) == pytest.approx(30.0) and c.mono == pytest.approx(1030.0)
    finally:
        d._shutdown_bus()


# --------------------------------------------------------------------------- counters


class SecondWriterNode(NodeImage):
    """A node image that runs ``during_put`` once, inside the first ``put``: after the first
    writer took its receive time, before it recorded it."""

    __slots__ = ("during_put",)

    def put(self, names: tuple[str, ...], values: tuple[Any, ...], ts: float, mono: float) -> None:
        hook, self.during_put = self.during_put, None
        if hook is not None:
            hook()
        super().put(names, values, ts, mono)


def test_the_last_receive_time_never_goes_back_when_two_threads_write_at_once() -> None:
    """The event loop writes a value read by SDO and the reader thread a TPDO at once: the
    reader's later receive time must stay the node's last one (data age, /healthz)."""
    image = ProcessImage()
    node = SecondWriterNode("n", 1, "sgh10", ["a", "b"])
    node.bind(("a",))
    node.bind(("b",))
    image.add_node(node)
    reader_times: list[float] = []

    def reader_writes() -> None:
        def run() -> None:
            image.update(node, ("b",), (2,), 0.0)
            reader_times.append(node.rx.last_rx_monotonic)

        t = threading.Thread(target=run)
        t.start()
        t.join(WAIT_S)

    node.during_put = reader_writes
    image.update(node, ("a",), (1,), 0.0)  # took its time first, records it last
    assert reader_times and node.rx.last_rx_monotonic == reader_times[0]
    assert node.signals["b"].monotonic == reader_times[0] >= node.signals["a"].monotonic


def test_receive_counters_of_two_threads_are_summed() -> None:
    node = NodeImage("n", 1, "sgh10", ["a"])
    cells = [node.rx.new_cell(), node.rx.new_cell()]
    cells[0].pdo_too_short, cells[1].pdo_too_short = 3, 4
    cells[0].pdo_too_long, cells[1].pdo_too_long = 1, 0
    cells[0].last_rx_monotonic, cells[1].last_rx_monotonic = 5.0, 7.0
    assert (node.rx.pdo_too_short, node.rx.pdo_too_long) == (7, 1)
    assert node.rx.last_rx_monotonic == 7.0


@contextmanager
def switch_interval(seconds: float) -> Iterator[None]:
    old = sys.getswitchinterval()
    sys.setswitchinterval(seconds)
    try:
        yield
    finally:
        sys.setswitchinterval(old)


def test_a_count_made_on_several_threads_is_exact() -> None:
    from canopen_gateway.runtime.threads import ThreadCount

    count = ThreadCount()
    start = threading.Barrier(3)

    def publish() -> None:
        start.wait(WAIT_S)
        for _ in range(50_000):
            count.add()

    with switch_interval(1e-6):
        threads = [threading.Thread(target=publish) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert count.value == 150_000
