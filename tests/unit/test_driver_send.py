"""The sender thread and a full transmit queue (``bus/driver.py``): a frame the interface
refuses with ENOBUFS (python-can's socketcan backend: ``CanOperationError`` with that
``error_code``; a SocketCAN queue holds 10 frames by default) is sent again a few times before
it counts as a bus error; while the queue does not drain at all (bus off), the frames that
follow are not held up by retries; any other refusal is not retried. A virtual bus whose
``send`` the test scripts."""

from __future__ import annotations

import errno
import uuid

import can

from canopen_gateway.bus.driver import SEND_FAILURES_DOWN, TX_RETRIES, BusDriver
from canopen_gateway.image import ProcessImage
from tests.helpers import wait_until_sync

ENOBUFS = can.CanOperationError("Failed to transmit: No buffer space available", errno.ENOBUFS)


def scripted(refusals: list[Exception | None]) -> tuple[BusDriver, list[int]]:
    """A driver whose bus refuses its sends with ``refusals`` in turn (None: accepted; when
    the list is used up, every send is accepted); returns it and the data byte of each
    attempt."""
    d = BusDriver({"interface": "virtual", "channel": f"tx-{uuid.uuid4().hex}"}, ProcessImage())
    d.open()
    attempts: list[int] = []

    def send(msg: can.Message, timeout: float | None = None) -> None:
        attempts.append(msg.data[0])
        exc = refusals.pop(0) if refusals else None
        if exc is not None:
            raise exc

    assert d.bus is not None
    d.bus.send = send  # type: ignore[method-assign]
    return d, attempts


def test_a_frame_refused_while_the_transmit_queue_is_full_is_sent_again() -> None:
    d, attempts = scripted([ENOBUFS, ENOBUFS])
    try:
        d.send(0x77F, b"\x05")
        wait_until_sync(lambda: d.image.counters["frames_out"] == 1, what="the frame sent")
        assert attempts == [5, 5, 5]
        assert d.image.counters["bus_errors"] == 0
    finally:
        d.close()


def test_a_queue_that_does_not_drain_costs_one_frame_its_retries_not_every_frame() -> None:
    d, attempts = scripted([ENOBUFS] * (TX_RETRIES + 1) + [ENOBUFS, None, ENOBUFS])
    try:
        for data in (1, 2, 3, 4):
            d.send(0x77F, bytes([data]))
        wait_until_sync(lambda: d.image.counters["frames_out"] == 2, what="frames 3 and 4 sent")
        # frame 1: its first attempt and every retry refused; frame 2: tried once (the queue
        # still full); frame 3 sent (the queue drains again); frame 4 refused once, sent again
        assert attempts == [1] * (TX_RETRIES + 1) + [2, 3, 4, 4]
        assert d.image.counters["bus_errors"] == 2
    finally:
        d.close()


def test_a_refusal_other_than_a_full_queue_is_not_retried() -> None:
    d, attempts = scripted([can.CanOperationError("adapter unplugged")])
    try:
        d.send(0x77F, b"\x01")
        d.send(0x77F, b"\x02")
        wait_until_sync(lambda: d.image.counters["frames_out"] == 1, what="frame 2 sent")
        assert attempts == [1, 2]
        assert d.image.counters["bus_errors"] == 1
    finally:
        d.close()


def watched(refusals: list[Exception | None]) -> tuple[BusDriver, list[int], list[tuple[str, str]]]:
    """``scripted`` with the states the driver reports (``on_state``) recorded."""
    d, attempts = scripted(refusals)
    states: list[tuple[str, str]] = []
    d.on_state = lambda state, detail: states.append((state, detail))
    d.reopen_backoff_s = 0.01
    return d, attempts, states


def test_a_send_refused_because_the_link_is_gone_takes_the_bus_down_and_it_is_reopened() -> None:
    """python-can's socketcand bus after its server closed: ``BrokenPipeError`` (EPIPE); a
    SocketCAN interface down or unplugged: ENETDOWN / ENODEV."""
    d, attempts, states = watched([BrokenPipeError(errno.EPIPE, "Broken pipe")])
    try:
        d.send(0x77F, b"\x05")
        wait_until_sync(lambda: ("ok", "") in states, what="the bus down and reopened")
        assert states[0] == ("down", "send failed: [Errno 32] Broken pipe")
        assert d.reopens == 1 and d.image.counters["bus_errors"] == 1
        assert attempts == [5]
    finally:
        d.close()


def test_refusals_without_errno_take_the_bus_down_after_several_in_a_row() -> None:
    other = can.CanOperationError("adapter not found")  # a vendor backend: no errno
    d, attempts, states = watched([other] * (SEND_FAILURES_DOWN - 1) + [None, other])
    try:
        for data in range(SEND_FAILURES_DOWN + 1):  # one sent between: the count starts over
            d.send(0x77F, bytes([data]))
        wait_until_sync(lambda: len(attempts) == SEND_FAILURES_DOWN + 1, what="every frame tried")
        wait_until_sync(lambda: d.state == "ok", what="ok: a frame went out")
        assert "down" not in [s for s, _ in states]  # refused: error, then ok; never down
        d.close()
        d, attempts, states = watched([other] * SEND_FAILURES_DOWN)
        for data in range(SEND_FAILURES_DOWN):
            d.send(0x77F, bytes([data]))
        wait_until_sync(lambda: ("down", "send failed: adapter not found") in states,
                        what="the bus down")  # fmt: skip
    finally:
        d.close()


def test_a_full_transmit_queue_never_takes_the_bus_down_but_says_its_frames_cannot_go_out() -> None:
    refusals: list[Exception | None] = [ENOBUFS] * (3 * SEND_FAILURES_DOWN * (TX_RETRIES + 1))
    d, attempts, states = watched(refusals)
    try:
        for data in range(3 * SEND_FAILURES_DOWN):
            d.send(0x77F, bytes([data]))
        wait_until_sync(lambda: d.image.counters["bus_errors"] == 3 * SEND_FAILURES_DOWN,
                        what="every frame refused")  # fmt: skip
        wait_until_sync(lambda: d.state == "error", what="the state error")
        assert [s for s, _ in states] == ["error"] and "transmit queue full" in states[0][1]
        refusals.clear()
        d.send(0x77F, b"\x01")  # the queue drains: the frame goes out, the bus is ok again
        wait_until_sync(lambda: d.state == "ok", what="ok again")
        assert [s for s, _ in states] == ["error", "ok"]
    finally:
        d.close()


def test_a_controller_that_says_bus_off_through_python_can_bus_state_is_an_error() -> None:
    d, _attempts, states = watched([])
    try:
        assert d.bus is not None
        type(d.bus).state = property(lambda self: can.BusState.ERROR)  # type: ignore[method-assign,assignment]
        wait_until_sync(lambda: d.state == "error", what="bus off from bus.state")
        assert states[0] == ("error", "bus off")
        type(d.bus).state = property(lambda self: can.BusState.ACTIVE)  # type: ignore[method-assign,assignment]
        wait_until_sync(lambda: d.state == "ok", what="error active again")
    finally:
        del type(d.bus).state  # type: ignore[union-attr]
        d.close()
