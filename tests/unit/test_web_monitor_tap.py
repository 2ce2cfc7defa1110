"""The bus monitor's tap, hand-off and budget (``canopen_gateway.web.monitor``), driven by direct calls
on a fake loop and a fake clock: the tap is installed only while a page is open; the reader
thread only appends raw tuples and wakes the loop once per armed period, never decodes; the
loop applies the filters before the budget of lines a second, decodes only what is shown, says
how many frames were skipped, and counts what overflowed the hand-off ring."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import can
import pytest

from canopen_gateway.northbound.frames import FrameDecoder
from canopen_gateway.web import monitor as mon
from canopen_gateway.web.monitor import MAX_LINES_PER_S, FrameMonitor, TooManyPages
from tests.helpers import make_config, with_nodes

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}


class FakeDriver:
    """What the monitor sees of ``BusDriver``: its taps, as the reader calls them."""

    def __init__(self) -> None:
        self.frame_taps: tuple[Callable[[Any], None], ...] = ()

    def add_tap(self, tap: Callable[[Any], None]) -> None:
        self.frame_taps = (*self.frame_taps, tap)

    def remove_tap(self, tap: Callable[[Any], None]) -> None:
        self.frame_taps = tuple(t for t in self.frame_taps if t != tap)

    def receive(self, cob_id: int, data: bytes = b"", ts: float = 1_700_000_000.0) -> None:
        msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, timestamp=ts)
        for tap in self.frame_taps:  # as BusDriver._run does
            tap(msg)


class FakeLoop:
    """Records ``call_soon_threadsafe`` and ``call_later``; the test runs them."""

    def __init__(self) -> None:
        self.soon: list[Callable[[], None]] = []
        self.later: list[tuple[float, Callable[[], None]]] = []

    def call_soon_threadsafe(self, fn: Callable[[], None]) -> None:
        self.soon.append(fn)

    def call_later(self, delay: float, fn: Callable[[], None]) -> None:
        self.later.append((delay, fn))

    def run_soon(self) -> None:
        todo, self.soon = self.soon, []
        for fn in todo:
            fn()

    def run_later(self) -> None:
        todo, self.later = self.later, []
        for _, fn in todo:
            fn()


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def tpdo1(position: int) -> bytes:
    return position.to_bytes(4, "little", signed=True) + bytes(2)


@pytest.fixture
def rig() -> tuple[FrameMonitor, FakeDriver, FakeLoop, Clock]:
    driver, loop, clock = FakeDriver(), FakeLoop(), Clock()
    cfg = make_config([WIRE, DISPLAY])
    m = FrameMonitor(cfg, FrameDecoder(*with_nodes(cfg)), driver, clock=clock)
    m.attach(loop)  # type: ignore[arg-type]
    return m, driver, loop, clock


def lines(page: Any) -> list[dict[str, Any]]:
    out = list(page.lines)
    page.lines.clear()
    return out


def test_the_tap_is_installed_only_while_a_page_is_open(rig: Any) -> None:
    m, driver, loop, _ = rig
    assert driver.frame_taps == ()  # nobody watching: the reader checks one attribute
    a = m.open()
    assert driver.frame_taps == (m.on_frame,)
    b = m.open()
    m.close(a)
    assert driver.frame_taps == (m.on_frame,)  # one page still open
    m.close(b)
    assert driver.frame_taps == ()
    driver.receive(0x181, tpdo1(5))
    assert m.tapped == 0 and loop.soon == []


def test_the_reader_appends_raw_frames_and_wakes_the_loop_once_per_armed_period(
    rig: Any,
) -> None:
    m, driver, loop, _ = rig
    page = m.open()
    decoded_before = m.decoded
    for i in range(1000):
        driver.receive(0x181, tpdo1(i))
    assert m.handoffs == 1 and len(loop.soon) == 1  # one call_soon_threadsafe for 1000 frames
    assert m.decoded == decoded_before and not page.lines  # nothing decoded on the reader
    loop.run_soon()
    assert m.batches == 1 and m.taken == 1000
    assert len(loop.later) == 1  # stays armed one period while frames flow
    driver.receive(0x181, tpdo1(7))
    assert len(loop.soon) == 0  # armed: no new hand-off
    loop.run_later()  # takes the one frame, stays armed
    assert m.taken == 1001 and m.handoffs == 1
    loop.run_later()  # nothing came: disarms
    assert loop.later == []
    driver.receive(0x181, tpdo1(8))
    assert m.handoffs == 2 and len(loop.soon) == 1


def test_lines_are_decoded_in_canopen_words_with_signal_names(rig: Any) -> None:
    m, driver, loop, _ = rig
    page = m.open()
    driver.receive(0x181, tpdo1(100))
    driver.receive(0x081, bytes([0x00, 0x50, 0x01, 0, 0, 0, 0, 0]))
    driver.receive(0x581, bytes([0x80, 0x00, 0x60, 0x00, 0x00, 0x00, 0x02, 0x06]))
    driver.receive(0x77D, b"\x05")
    driver.receive(0x000, bytes([0x02, 0x01]))
    loop.run_soon()
    got = lines(page)
    assert [(g["cob_id"], g["node"], g["kind"], g["service"]) for g in got] == [
        ("181", "wire", "pdo", "TPDO1"),
        ("081", "wire", "emcy", "EMCY"),
        ("581", "wire", "sdo", "SDO answer"),
        ("77D", "display", "heartbeat", "heartbeat"),
        ("000", "wire", "nmt", "NMT"),
    ]
    assert got[0]["text"] == "position=10 mm velocity=0 mm/s"
    assert got[0]["data"] == "64 00 00 00 00 00" and got[0]["dir"] == "rx"
    assert got[1]["text"].startswith("0x5000 (")
    assert got[2]["text"] == (
        "abort 0x6000:00 (Operating parameters): 0x06020000 Object does not exist in the "
        "object dictionary"
    )
    assert got[3]["text"] == "operational"
    assert got[4]["text"] == "stop to node id 1"


def test_the_budget_shows_the_first_lines_of_each_second_and_counts_the_rest(
    rig: Any,
) -> None:
    m, driver, loop, clock = rig
    page = m.open()
    n = MAX_LINES_PER_S + 250
    for i in range(n):
        driver.receive(0x181, tpdo1(i))
    loop.run_soon()
    got = lines(page)
    assert len(got) == MAX_LINES_PER_S + 1
    assert got[-1]["skipped"] == 250  # one line says how many were not shown
    assert page.skipped == 250 and page.shown == MAX_LINES_PER_S
    assert m.decoded == MAX_LINES_PER_S  # skipped frames are never decoded
    driver.receive(0x181, tpdo1(1))
    loop.run_later()
    assert [g.get("skipped") for g in lines(page)] == [1]  # the same second: still over
    clock.now += 1.0
    driver.receive(0x181, tpdo1(2))
    loop.run_later()
    assert [g["text"] for g in lines(page)] == ["position=0.2 mm velocity=0 mm/s"]


def test_filters_apply_before_the_budget(rig: Any) -> None:
    m, driver, loop, _ = rig
    everything = m.open()
    emcy_only = m.open(None, frozenset({"emcy"}))
    display_only = m.open(frozenset({125}), None)
    for i in range(3 * MAX_LINES_PER_S):
        driver.receive(0x181, tpdo1(i))
    driver.receive(0x0FD, bytes([0x10, 0xFF, 0x81, 0, 0, 0, 0, 0]))  # display's EMCY, last
    driver.receive(0x77D, b"\x05")
    loop.run_soon()
    assert [g["node"] for g in lines(emcy_only)] == ["display"]
    assert [(g["kind"], g["node"]) for g in lines(display_only)] == [
        ("emcy", "display"), ("heartbeat", "display")
    ]  # fmt: skip
    assert lines(everything)[-1]["skipped"] == 2 * MAX_LINES_PER_S + 2
    assert emcy_only.matched == 1 and emcy_only.skipped == 0


def test_a_reader_far_ahead_of_the_loop_loses_the_oldest_frames_and_says_how_many(
    rig: Any,
) -> None:
    m, driver, loop, _ = rig
    m._ring = type(m._ring)(maxlen=10)  # a hand-off ring of 10 frames instead of HANDOFF_MAX
    page = m.open()
    for i in range(25):
        driver.receive(0x181, tpdo1(i))
    assert m.lost == 15
    loop.run_soon()
    got = lines(page)
    assert got[0]["text"].startswith("position=1.5 mm")  # the newest 10 were kept
    assert page.status(m.lost)["lost"] == 15


def test_filters_are_checked_with_the_words_of_the_monitor_command(rig: Any) -> None:
    m, _, _, _ = rig
    assert m.parse_filters(["wire", "5"], ["pdo", "emcy"]) == (
        frozenset({1, 5}), frozenset({"pdo", "emcy"})
    )  # fmt: skip
    assert m.parse_filters([""], [""]) == (None, None)
    with pytest.raises(ValueError, match="'pump': not a node of the config"):
        m.parse_filters(["pump"], [])
    with pytest.raises(ValueError, match="kinds are nmt, sync"):
        m.parse_filters([], ["pdos"])


def test_pages_are_bounded_and_a_console_without_a_bus_refuses(rig: Any) -> None:
    m, _, _, _ = rig
    for _ in range(mon.MAX_PAGES):
        m.open()
    with pytest.raises(TooManyPages, match="at most 8 monitor pages"):
        m.open()
    cfg = make_config([WIRE])
    busless = FrameMonitor(cfg, FrameDecoder(*with_nodes(cfg)), None)
    assert busless.refusal() == "this gateway has no bus to monitor"


def test_a_page_that_does_not_read_keeps_its_newest_lines_and_counts_the_dropped(
    rig: Any,
) -> None:
    m, driver, loop, clock = rig
    page = m.open()
    for second in range(7):  # 700 lines for a queue of 500
        clock.now += 1.0
        for i in range(MAX_LINES_PER_S):
            driver.receive(0x181, tpdo1(second * 1000 + i))
        loop.run_soon()
        loop.run_later()
        loop.run_later()
    assert len(page.lines) == mon.MAX_PENDING
    assert page.dropped == 7 * MAX_LINES_PER_S - mon.MAX_PENDING
