"""Pure parts of the console's first-hour features, on a fake clock: the trend store (quality
kept with every sample, bounded ring, only numeric TPDO signals), the event log (state changes
and EMCY from health, warnings from the log, filters, bounded, exact under threads) and the
per-client read budget."""

from __future__ import annotations

import logging
import threading

from canopen_gateway.canopen.states import NmtState
from canopen_gateway.image import EmcyRecord, NodeImage, ProcessImage, Quality
from canopen_gateway.northbound.scaling import Scaling
from canopen_gateway.profiles import load_profile
from canopen_gateway.web.events import EventLog, EventLogHandler
from canopen_gateway.web.limits import ClientBudget
from canopen_gateway.web.trends import TrendStore, is_trend_signal
from canopen_gateway.web.views import SignalMeta


def _meta(name: str, source: str = "TPDO") -> SignalMeta:
    sig = next(s for s in load_profile("sgh10").profile.signals if s.name == name)
    return SignalMeta(sig, Scaling.of(sig, None), source, "", ())


def _store(samples: int = 600) -> tuple[TrendStore, NodeImage]:
    image = ProcessImage()
    node = NodeImage("wire", 1, "sgh10", ["position", "velocity", "alarms"])
    node.bind(("position", "velocity"))  # as the master binds a TPDO's record when it builds the node
    image.add_node(node)
    metas = {n: _meta(n) for n in ("position", "velocity", "alarms")}
    return TrendStore(image, {"wire": metas}, samples=samples), node


def _operational(node: NodeImage, since: float) -> None:
    node.health.alive = True
    node.health.nmt_state = NmtState.OPERATIONAL
    node.health.fresh_since = since


def test_only_numeric_process_values_without_bits_are_trend_signals() -> None:
    assert is_trend_signal(_meta("position"))
    assert not is_trend_signal(_meta("alarms"))  # a bit field
    assert not is_trend_signal(_meta("position", source="SDO"))
    store, _ = _store()
    assert [m.sig.name for m in store.signals["wire"]] == ["position", "velocity"]


def test_a_sample_keeps_quality_and_never_draws_stale_or_bad_as_good() -> None:
    store, node = _store()
    store.sample(10.0, 1000.0)  # nothing received yet: bad, no value
    _operational(node, since=10.0)
    node.put(("position", "velocity"), (1234, 5), 1000.5, 10.5)
    store.sample(11.0, 1001.0)
    node.health.alive = False  # lost: the last known value is stale
    store.sample(12.0, 1002.0)
    node.health.alive = True
    node.health.invalid_signals = frozenset({"position"})  # the device says invalid: bad
    store.sample(13.0, 1003.0)
    doc = store.since("wire")
    assert doc["t"] == [1000.0, 1001.0, 1002.0, 1003.0]
    position, velocity = doc["values"]
    assert doc["quality"][0] == [Quality.BAD, Quality.GOOD, Quality.STALE, Quality.BAD]
    assert position == [None, 123.4, 123.4, None]  # engineering units: 0.1 mm a count
    assert doc["quality"][1] == [Quality.BAD, Quality.GOOD, Quality.STALE, Quality.GOOD]
    assert doc["signals"][0]["unit"] == "mm"


def test_a_value_of_before_the_last_start_is_stale_in_the_trend() -> None:
    store, node = _store()
    node.put(("position", "velocity"), (7, 0), 999.0, 9.0)
    _operational(node, since=10.0)  # started again after that frame
    store.sample(11.0, 1001.0)
    assert store.since("wire")["quality"][0] == [Quality.STALE]


def test_the_ring_is_bounded_and_since_gives_only_newer_samples() -> None:
    store, node = _store(samples=3)
    _operational(node, since=0.0)
    for i in range(5):
        node.put(("position", "velocity"), (i, 0), 100.0 + i, 1.0 + i)
        store.sample(1.5 + i, 100.5 + i)
    doc = store.since("wire")
    assert doc["values"][0] == [0.2, 0.3, 0.4] and doc["seq"] == 5
    assert store.since("wire", after=4)["values"][0] == [0.4]
    assert store.since("wire", after=5)["t"] == []
    assert store.since("nope")["signals"] == []


def test_health_changes_and_emcy_become_events_of_their_node() -> None:
    log = EventLog(["wire", "wire2"], clock=lambda: 50.0)
    node = NodeImage("wire", 1, "sgh10", ["position"])
    log.watch(node)
    log.on_health(node, "health")  # nothing changed: no event
    assert log.since() == []
    node.health.alive = True
    node.health.boot_count = 1
    node.health.nmt_state = NmtState.OPERATIONAL
    log.on_health(node, "state")
    (ev,) = log.since()
    assert ev.kind == "state" and ev.node == "wire" and ev.ts == 50.0
    assert ev.text == "wire: presence not seen -> alive, NMT state unknown -> operational"
    node.health.last_emcy = EmcyRecord(0x1000, 1, b"", "Generic error", 42.0)
    node.health.emcy_count = 3  # three since the last event: one event, saying so
    log.on_health(node, "emcy")
    ev = log.since(after=1)[0]
    assert ev.kind == "emcy" and ev.ts == 42.0
    assert ev.text == "wire: EMCY 0x1000 Generic error (and 2 more since the last event)"
    assert [e.kind for e in log.since(kinds=["emcy"])] == ["emcy"]
    assert log.since(node="wire2") == []


def test_log_records_are_filed_under_the_node_they_name_and_the_ring_is_bounded() -> None:
    log = EventLog(["wire", "wire2"], max_events=100)
    logger = logging.getLogger("gateway.test.events")
    handler = EventLogHandler(log)
    logger.addHandler(handler)
    try:
        logger.info("not kept: below WARNING")
        logger.warning("node %s lost", "wire2")
        logger.error("a wired problem of nobody")
        threads = [
            threading.Thread(target=lambda: [logger.warning("w") for _ in range(100)])
            for _ in range(4)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        logger.removeHandler(handler)
    events = log.since()
    assert len(events) == 100 and log.seq == 402  # every record counted, the last 100 kept
    assert [e.seq for e in events] == list(range(303, 403))
    first = EventLog(["wire", "wire2"])
    first.append("warning", first.node_named_in("node wire2 lost"), "node wire2 lost")
    assert first.since()[0].node == "wire2"
    assert first.node_named_in("a wired problem of nobody") is None


def test_the_read_budget_refuses_past_the_burst_and_says_when_to_retry() -> None:
    now = [0.0]
    budget = ClientBudget(2.0, 5, clock=lambda: now[0], max_clients=2)
    assert [budget.take("a") for _ in range(5)] == [0.0] * 5
    assert budget.take("a") == 0.5  # one token comes back in half a second
    assert budget.take("b") == 0.0  # another client has its own budget
    now[0] = 0.5
    assert budget.take("a") == 0.0
    assert budget.take("a") == 0.5
    now[0] = 100.0
    assert budget.take("c") == 0.0  # a third client: the quiet ones are forgotten
    assert len(budget._buckets) <= 2 and budget.refused == 2
