"""Which value of a signal wins, and whether it is fresh, is decided by when the value was valid
at the device, on the bus clock that ``fresh_since`` is on: a TPDO's receive time, a value read
by SDO the time its request went out. Not by when the reader thread or the event loop got to it.

The master runs with its real handlers (the reader side of a TPDO, the event loop side of an
SDO answer) on one fake clock: the driver's monotonic and wall clocks and the image's clock.
The SGH10 here sends TPDO1 (position, velocity) on change only, without RTR, so after NMT start
the gateway reads both by SDO (``pdo/refresh.py``); each signal is then in two records.
"""

from __future__ import annotations

import struct
import types
from typing import Any

import can
import pytest

import canopen_gateway.image
from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.master import Master
from canopen_gateway.bus.node.parts import NodeParts
from canopen_gateway.image import ProcessImage, Quality
from tests.helpers import make_config, resolved

#: SGH10 whose TPDO1 sends on change only and allows no RTR (DS-301 1800h:01 bit 30)
WIRE = {
    "name": "wire",
    "node_id": 1,
    "profile": "sgh10",
    "sdo": [{"object": "0x1800:05", "value": 0}, {"object": "0x1800:01", "value": 0x40000181}],
}
POSITION, VELOCITY = (0x6020, 1), (0x6030, 1)  # TPDO1's objects (SGH10 manual 4.3.2)


class Bench:
    """The master of one SGH10, its frames sent recorded, on one fake clock (``mono``, with
    the wall clock in step); the device's answers are delivered by the test."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.mono, self.offset = 5000.0, 1_700_000_000.0
        cfg = make_config([WIRE], modbus={"enabled": False}, zenoh={"enabled": False})
        self.image = ProcessImage()
        self.driver = BusDriver(
            cfg.can.bus_kwargs(), self.image, mono=lambda: self.mono, wall=self.wall
        )
        self.sent: list[tuple[float, int, bytes]] = []
        monkeypatch.setattr(self.driver, "send", self._send)
        # the image's own clock (a write without a time of its own) is the same fake clock
        fake_time = types.SimpleNamespace(monotonic=lambda: self.mono, time=self.wall)
        monkeypatch.setattr(canopen_gateway.image, "time", fake_time)
        self.master = Master(cfg, self.image, self.driver, nodes=resolved(cfg))
        self.p: NodeParts = self.master.nodes["wire"]
        self.node = self.p.image
        self.answered = 0  # SDO requests answered so far

    def wall(self) -> float:
        return self.mono + self.offset

    def _send(self, cob_id: int, data: bytes = b"", rtr: bool = False, dlc: Any = None) -> None:
        self.sent.append((self.mono, cob_id, bytes(data)))

    def advance(self, dt_s: float) -> None:
        self.mono += dt_s

    # -- the device
    def frame(self, cob_id: int, data: bytes) -> can.Message:
        """A frame received now (its timestamp is the wall clock, as python-can stamps it)."""
        return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False, timestamp=self.wall())  # fmt: skip

    def control(self, kind: str, msg: can.Message) -> None:
        """The event loop handles a control frame (received at ``msg.timestamp``) now."""
        self.master._on_control(self.p, kind, bytes(msg.data), msg.timestamp, self.driver.frame_time(msg))  # fmt: skip

    def tpdo(self, msg: can.Message) -> None:
        """The reader thread handles a TPDO now (its handler, on this thread)."""
        self.driver.handlers[msg.arbitration_id](msg)

    def requests(self) -> list[tuple[float, bytes]]:
        return [(t, d) for t, cob, d in self.sent if cob == 0x601]

    def pending(self) -> bytes | None:
        reqs = self.requests()
        return reqs[self.answered][1] if len(reqs) > self.answered else None

    def answer(self, values: dict[tuple[int, int], int]) -> can.Message:
        """The answer to the oldest unanswered SDO request: a download confirmed, an upload
        with ``values`` (int32 little endian)."""
        req = self.pending()
        assert req is not None
        self.answered += 1
        index, sub = struct.unpack_from("<HB", req, 1)
        if req[0] == 0x40:
            return self.frame(0x581, bytes([0x43]) + req[1:4] + struct.pack("<i", values[(index, sub)]))  # fmt: skip
        return self.frame(0x581, bytes([0x60]) + req[1:4] + b"\0" * 4)

    def boot_and_configure(self, *, all_but_last: bool = False) -> None:
        """Boot-up, then each boot step answered 1 ms after its request (all, or all but the
        last: its answer is left to the test)."""
        self.master._execute(self.p, self.p.node.start(self.mono, probe=False))
        self.control("nmt_ec", self.frame(0x701, b"\x00"))
        identity = dict(((o.index, o.sub), v) for o, v in self.p.node.lifecycle.expected_identity)
        steps = len(identity) + len(self.p.boot_steps)  # 1018h read first, as its EDS gives it
        while self.answered < steps - (1 if all_but_last else 0):
            self.advance(0.001)
            self.control("sdo", self.answer(identity))

    def nmt_start_time(self) -> float:
        return next(t for t, cob, d in self.sent if cob == 0x000 and d[0] == 0x01)

    def quality(self, name: str) -> Quality:
        return self.node.quality(self.node.signals[name], self.mono)


def tpdo1(position: int, velocity: int) -> bytes:
    return struct.pack("<ih", position, velocity)


def test_an_sdo_refresh_answered_after_a_newer_tpdo_does_not_overwrite_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """NMT start; the refresh asks position by SDO; the device's position changes and TPDO1
    brings 222 before the SDO answer (111, the value when the request came) is handled: 222
    stays. Velocity is asked after that TPDO: its SDO answer is the newer value and wins."""
    b = Bench(monkeypatch)
    b.boot_and_configure()
    started = b.nmt_start_time()
    assert b.node.health.fresh_since == pytest.approx(started, abs=1e-6)  # receive time
    b.control("nmt_ec", b.frame(0x701, b"\x05"))  # heartbeat: operational
    t_request, request = b.requests()[-1]
    assert request[:4] == b"\x40\x20\x60\x01" and t_request == started  # position, at once
    b.advance(0.001)
    b.tpdo(b.frame(0x181, tpdo1(222, 7)))  # received and handled before the SDO answer
    b.advance(0.001)
    b.control("sdo", b.answer({POSITION: 111}))  # the value the device had at the request
    position = b.node.signals["position"]
    assert position.value == 222 and position.seq == 2
    assert b.quality("position") == Quality.GOOD
    # velocity: requested after the TPDO was received, so its answer is the newer value
    assert b.pending() == b"\x40\x30\x60\x01\0\0\0\0"
    b.advance(0.001)
    b.control("sdo", b.answer({VELOCITY: 8}))
    assert b.node.signals["velocity"].value == 8
    # and a TPDO after that wins again
    b.advance(0.001)
    b.tpdo(b.frame(0x181, tpdo1(333, 9)))
    assert (b.node.signals["position"].value, b.node.signals["velocity"].value) == (333, 9)


def test_a_tpdo_received_before_nmt_start_but_handled_after_it_is_not_fresh(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The reader is 100 ms behind the bus: a TPDO received 10 ms before the last boot step's
    answer is handled first, then the answer, and the loop starts the node as of the answer's
    receive time (the bus clock of its events). The TPDO was received before: stale, however
    late it was handled; a TPDO received after NMT start: good."""
    b = Bench(monkeypatch)
    b.boot_and_configure(all_but_last=True)
    b.advance(0.001)
    early = b.frame(0x181, tpdo1(-5, 0))
    b.advance(0.01)
    last_answer = b.answer({})
    b.advance(0.09)  # the reader gets to both now, in the order received
    b.tpdo(early)
    b.control("sdo", last_answer)
    assert b.node.health.fresh_since == b.driver.frame_time(last_answer)
    b.control("nmt_ec", b.frame(0x701, b"\x05"))  # heartbeat: operational
    assert b.node.signals["position"].value == -5
    assert b.quality("position") == Quality.STALE
    b.advance(0.001)
    b.tpdo(b.frame(0x181, tpdo1(6, 0)))
    assert b.node.signals["position"].value == 6
    assert b.quality("position") == Quality.GOOD
