"""CiA 305 LSS Fast Scan: our master's steps (``canopen_gateway.bus.lss.fastscan``) find the
unconfigured slave with the lowest LSS address among identical devices whose serial numbers
are unknown, against slaves scripted here from CiA 305 (as CANopenNode's CO_LSSslave answers)
and against our simulator's LSS slave (``sim.features.lss_slave``), which leaves the one found
in LSS configuration; a configured slave and a slave in configuration stay silent."""

from __future__ import annotations

import struct
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_gateway.bus.lss.fastscan import FastScan
from canopen_gateway.sim.features.lss_slave import CONFIGURATION, WAITING, LssSlave

Address = tuple[int, int, int, int]


class ScriptedSlave:
    """CiA 305 Fast Scan, the slave's side, written from the standard: an unconfigured slave
    answers 4Fh to BitChecked 80h (and goes back to part 0), or when part LSSSub is the one it
    compares and equals IDNumber in bits 31..BitChecked (then it compares part LSSNext)."""

    def __init__(self, address: Address):
        self.address = address
        self.part = 0
        self.configuration = False

    def answers(self, frame: bytes) -> bool:
        cs, id_number, bit, sub, nxt = struct.unpack("<BIBBB", frame)
        assert cs == 0x51
        if self.configuration:
            return False
        if bit == 0x80:
            self.part = 0
            return True
        mask = (0xFFFFFFFF << bit) & 0xFFFFFFFF
        if sub != self.part or (self.address[sub] & mask) != (id_number & mask):
            return False
        self.part = nxt
        self.configuration = bit == 0 and nxt < sub
        return True


def run(scan: FastScan, slaves: list[Any]) -> FastScan:
    while (frame := scan.next_frame()) is not None:
        answers = [s.answers(frame) for s in slaves]  # every slave sees every frame
        scan.answered(any(answers))
    return scan


PART = st.integers(0, 0xFFFFFFFF)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(PART, PART, PART, PART), min_size=1, max_size=5, unique=True))
def test_finds_the_lowest_address_and_leaves_only_it_in_configuration(addresses: list[Address]) -> None:
    slaves = [ScriptedSlave(a) for a in addresses]
    scan = run(FastScan(), slaves)
    assert scan.found == min(addresses)
    assert [s.configuration for s in slaves] == [a == min(addresses) for a in addresses]
    assert scan.frames == 1 + 4 * 33


def test_identical_devices_differing_in_serial_only_with_the_known_parts_given() -> None:
    known = (0x195, 0xFFFFFFFF, 0xFFFFFFFF)
    slaves = [ScriptedSlave((*known, serial)) for serial in (0x5A17, 0x0103, 0x9000)]
    scan = run(FastScan((*known, None)), slaves)
    assert scan.found == (*known, 0x0103)
    assert scan.frames == 1 + 3 + 33  # the known parts confirmed at once


def test_no_unconfigured_slave_ends_at_the_reset() -> None:
    scan = run(FastScan(), [])
    assert scan.found is None and scan.failed is not None and "no unconfigured" in scan.failed
    assert scan.frames == 1


class FakeNode:
    """What the LSS slave feature uses of its simulated node for Fast Scan."""

    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes]] = []

    def send(self, cob_id: int, data: bytes) -> None:
        self.sent.append((cob_id, bytes(data)))

    def get(self, index: int, sub: int, default: int = 0) -> int:
        return default


class SimSlave:
    """Our simulator's LSS slave, driven by frames, answering on 7E4h."""

    def __init__(self, serial: int, unconfigured: bool = True):
        self.node = FakeNode()
        self.lss = LssSlave(self.node, {"unconfigured": unconfigured, "vendor_id": 0x195,
                                        "product_code": 0xFFFFFFFF, "revision_number": 0xFFFFFFFF,
                                        "serial_number": serial})  # fmt: skip

    def answers(self, frame: bytes) -> bool:
        import can

        before = len(self.node.sent)
        self.lss.on_frame(can.Message(arbitration_id=0x7E5, data=frame, is_extended_id=False), 0.0)
        new = self.node.sent[before:]
        return any(cob == 0x7E4 and data[0] == 0x4F for cob, data in new)


def test_the_simulators_slave_answers_fast_scan_and_the_one_found_is_in_configuration() -> None:
    slaves = [SimSlave(serial) for serial in (77, 12, 40)]
    configured = SimSlave(1, unconfigured=False)  # a device with a node id takes no part
    scan = run(FastScan(), [*slaves, configured])
    assert scan.found == (0x195, 0xFFFFFFFF, 0xFFFFFFFF, 12)
    assert [s.lss.state for s in slaves] == [WAITING, CONFIGURATION, WAITING]
    assert configured.node.sent == []
    slaves[1].lss.configured_node_id = 5  # given a node id: silent from now on
    slaves[1].lss.state = WAITING
    assert run(FastScan(), slaves).found == (0x195, 0xFFFFFFFF, 0xFFFFFFFF, 40)
