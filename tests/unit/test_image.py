"""The process image: one PDO's values go in together, quality never calls an old value good,
counters are exact across threads."""

from __future__ import annotations

import threading

from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.image import NodeImage, ProcessImage, Quality, SignalValue


def node() -> NodeImage:
    n = NodeImage("n", 1, "sgh10", ["a", "b"])
    n.bind(("a", "b"))  # one PDO carries both (bound when the node is built)
    n.health.alive = True
    n.health.nmt_state = NmtState.OPERATIONAL
    return n


def test_a_reader_never_sees_two_frames_mixed() -> None:
    image = ProcessImage()
    n = node()
    image.add_node(n)
    stop = threading.Event()

    def writer() -> None:
        i = 0
        while not stop.is_set():
            i += 1
            image.update(n, ("a", "b"), (i, i), 0.0)

    t = threading.Thread(target=writer)
    t.start()
    try:
        mixed = 0
        for _ in range(200_000):
            snap = n.snapshot()
            if snap["a"].value != snap["b"].value:
                mixed += 1
    finally:
        stop.set()
        t.join()
    assert mixed == 0
    assert n.signals["a"].seq == n.signals["b"].seq > 0


def test_a_value_received_before_the_last_start_is_stale() -> None:
    n = node()
    n.health.fresh_since = 100.0
    assert n.quality(SignalValue("a", 1, 0.0, 99.9, 1), 101.0) == Quality.STALE
    assert n.quality(SignalValue("a", 1, 0.0, 100.0, 1), 101.0) == Quality.GOOD
    n.health.fresh_since = None  # booted or lost, not started again
    assert n.quality(SignalValue("a", 1, 0.0, 100.5, 1), 101.0) == Quality.STALE
    assert n.quality(SignalValue("a"), 101.0) == Quality.BAD  # never received


def test_usable_means_operational_and_a_confirmed_link() -> None:
    n = node()
    assert n.usable()
    n.health.link = LinkState.UNKNOWN
    assert n.operational() and not n.usable()
    n.health.link = LinkState.OK
    n.health.nmt_state = NmtState.PRE_OPERATIONAL
    assert not n.usable()


def test_counters_counted_by_several_threads_are_exact() -> None:
    image = ProcessImage()

    def count() -> None:
        c = image.counters.counter_set()
        for _ in range(100_000):
            c["frames_in"] += 1

    threads = [threading.Thread(target=count) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    image.count("frames_in", 5)
    assert image.counters["frames_in"] == 300_005
