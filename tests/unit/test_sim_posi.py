"""The simulated BEI IDEACOD POSI+ / POSI+ SF, driven with raw CAN frames and a fake clock.

Covers the simulation of the profile features pdo_type_selector (2005h), cams (6300h-6320h),
heartbeat_consumer (1016h) and node_id_object (2101h/2100h, SF 6101h/6100h), and the SDO examples
of manual 002 section 2.2 byte for byte. The expected bytes are copied from the manual here, so
the tests run without it.
"""

from __future__ import annotations

import struct

import can
import pytest

from canopen_gateway.profiles import load_profile
from canopen_gateway.sim.node import SimNode
from canopen_gateway.sim.objects import PersistentStore
from tests.helpers import frame as can_frame

POSITION = 0x0012D687  # an arbitrary held position, bytes 87 D6 12 00


def frame(cob_id: int, *data: int) -> can.Message:
    """The manuals' byte lists as they are written: ``frame(0x601, 0x40, 0x04, 0x60, ...)``."""
    return can_frame(cob_id, bytes(data))


def make(
    family: str = "posi_plus",
    node_id: int = 1,
    *,
    position: int = POSITION,
    speed: float | None = None,
    top: int = 0x1FFFFFFF,
    store: PersistentStore | None = None,
) -> SimNode:
    """A powered node holding ``position``, or on a ramp 0 -> ``top`` -> 0 at ``speed`` counts/s."""
    if speed is None:
        motion = {"kind": "hold", "min": 0, "max": 0x1FFFFFFF, "hold": position, "start": None}
    else:
        motion = {"kind": "ramp", "min": 0, "max": 0x1FFFFFFF, "speed": speed, "start": 0}
        motion["max"] = top
    node = SimNode(load_profile(family), node_id, motion=motion, store=store)
    node.power_on(0.0)
    return node


def only(frames: list[can.Message], cob_id: int) -> bytes:
    hits = [bytes(f.data) for f in frames if f.arbitration_id == cob_id]
    assert len(hits) == 1, f"expected one frame on 0x{cob_id:03X}, got {frames}"
    return hits[0]


def sdo(node: SimNode, now: float, *data: int) -> bytes:
    """One SDO request (8 bytes) -> the 8-byte response on 0x580 + node id."""
    out = node.handle(frame(0x600 + node.node_id, *data), now)
    return only(out, 0x580 + node.node_id)


def write_u32(node: SimNode, now: float, index: int, sub: int, value: int) -> bytes:
    return sdo(node, now, 0x23, index & 0xFF, index >> 8, sub, *struct.pack("<I", value))


def write_u16(node: SimNode, now: float, index: int, sub: int, value: int) -> bytes:
    return sdo(node, now, 0x2B, index & 0xFF, index >> 8, sub, *struct.pack("<H", value), 0, 0)


def write_u8(node: SimNode, now: float, index: int, sub: int, value: int) -> bytes:
    return sdo(node, now, 0x2F, index & 0xFF, index >> 8, sub, value, 0, 0, 0)


def read(node: SimNode, now: float, index: int, sub: int = 0) -> bytes:
    return sdo(node, now, 0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0)


def ok(index: int, sub: int) -> bytes:
    return bytes([0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])


def abort(index: int, sub: int, code: int) -> bytes:
    return bytes([0x80, index & 0xFF, index >> 8, sub]) + struct.pack("<I", code)


def nmt(node: SimNode, now: float, cs: int, target: int = 0) -> list[can.Message]:
    return node.handle(frame(0x000, cs, target), now)


SAVE = (0x73, 0x61, 0x76, 0x65)  # "save" as sent on the bus (manual prints 6576 6173h)
LOAD = (0x6C, 0x6F, 0x61, 0x64)  # "load" as sent on the bus (manual prints 6461 6F6Ch)


# -- manual 002 section 2.2: SDO examples ----------------------------------------------------------
def test_position_request_40h_6004h_is_answered_43h_with_pos0_to_pos3() -> None:
    node = make()
    # 600h+node ID: 40 04 60 00 X X X X
    out = node.handle(frame(0x601, 0x40, 0x04, 0x60, 0x00, 0, 0, 0, 0), 0.1)
    # 580h+node ID: 43 04 60 00 Pos0 Pos1 Pos2 Pos3
    assert only(out, 0x581) == bytes([0x43, 0x04, 0x60, 0x00, 0x87, 0xD6, 0x12, 0x00])


def test_preset_write_22h_6003h_is_confirmed_60h_with_zero_data() -> None:
    node = make()
    # 600h+node ID: 22 03 60 00 Pre0 Pre1 Pre2 Pre3 (expedited, size not indicated)
    out = node.handle(frame(0x601, 0x22, 0x03, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00), 0.1)
    # 580h+node ID: 60 03 60 00 0 0 0 0
    assert only(out, 0x581) == bytes([0x60, 0x03, 0x60, 0x00, 0, 0, 0, 0])
    assert read(node, 0.2, 0x6003) == bytes([0x43, 0x03, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00])


def test_store_signature_is_save_little_endian_and_the_printed_order_is_refused() -> None:
    node = make()
    assert sdo(node, 0.1, 0x23, 0x10, 0x10, 0x01, *SAVE) == ok(0x1010, 1)
    # the bytes in the order the manual prints them ("evas") are not the signature
    assert sdo(node, 0.2, 0x23, 0x10, 0x10, 0x01, 0x65, 0x76, 0x61, 0x73) == abort(
        0x1010, 1, 0x08000020
    )
    assert sdo(node, 0.3, 0x23, 0x11, 0x10, 0x01, *LOAD) == ok(0x1011, 1)


def test_device_type_and_device_name_read_as_the_object_table() -> None:
    node = make()
    assert read(node, 0.1, 0x1000) == bytes([0x43, 0x00, 0x10, 0x00, 0x96, 0x01, 0x02, 0x00])
    # "POSI+" is 5 bytes: segmented upload, size 5, then one last segment with 2 unused bytes
    assert read(node, 0.1, 0x1008) == bytes([0x41, 0x08, 0x10, 0x00, 0x05, 0, 0, 0])
    assert sdo(node, 0.1, 0x60, 0, 0, 0, 0, 0, 0, 0) == bytes([0x05]) + b"POSI+\0\0"


# -- 2005h PDO type -------------------------------------------------------------------------------
def start_cyclic(node: SimNode, now: float, period_ms: int = 10) -> None:
    assert write_u16(node, now, 0x1800, 5, period_ms) == ok(0x1800, 5)
    nmt(node, now, 0x01, node.node_id)


def test_default_pdo_type_sends_position_only_in_4_bytes() -> None:
    node = make()
    start_cyclic(node, 0.1)
    tpdo1 = only(node.tick(0.1), 0x181)
    assert tpdo1 == struct.pack("<I", POSITION)
    tpdo2 = only(node.handle(frame(0x080), 0.105), 0x281)
    assert tpdo2 == struct.pack("<I", POSITION)


def test_pdo_type_02h_puts_speed_in_bytes_4_5_of_tpdo1_and_zeros_in_6_7() -> None:
    node = make(speed=8192.0)  # one revolution per second: 8192 * 0.005 = 40.96 steps/5 ms
    assert write_u8(node, 0.1, 0x2005, 0, 0x02) == ok(0x2005, 0)
    start_cyclic(node, 0.1)
    data = only(node.tick(0.5), 0x181)
    assert len(data) == 8
    position, speed, pad = struct.unpack("<IhH", data)
    assert position == round(8192.0 * 0.5)
    assert speed == 41
    assert pad == 0
    # PDO2 keeps the default type
    assert only(node.handle(frame(0x080), 0.5), 0x281) == struct.pack("<I", position)


def test_pdo_type_20h_changes_tpdo2_only_and_22h_both() -> None:
    node = make(speed=2048.0)
    assert write_u8(node, 0.1, 0x2005, 0, 0x20) == ok(0x2005, 0)
    start_cyclic(node, 0.1)
    assert len(only(node.tick(0.2), 0x181)) == 4
    assert len(only(node.handle(frame(0x080), 0.2), 0x281)) == 8
    nmt(node, 0.3, 0x80, 1)
    assert write_u8(node, 0.3, 0x2005, 0, 0x22) == ok(0x2005, 0)
    nmt(node, 0.3, 0x01, 1)
    assert len(only(node.tick(0.4), 0x181)) == 8
    assert len(only(node.handle(frame(0x080), 0.4), 0x281)) == 8


def test_speed_is_signed_negative_while_turning_back() -> None:
    node = make(speed=8192.0, top=4096)  # up for 0.5 s, then down at 8192 counts/s
    assert write_u8(node, 0.1, 0x2005, 0, 0x02) == ok(0x2005, 0)
    start_cyclic(node, 0.1)
    data = only(node.tick(0.75), 0x181)
    # position 2048 = 00 08 00 00, speed -41 = D7 FF, then 00 00
    assert data == bytes([0x00, 0x08, 0x00, 0x00, 0xD7, 0xFF, 0x00, 0x00])


def test_pdo_type_values_the_manual_does_not_list_are_refused_with_06090030h() -> None:
    node = make()
    for value in (0x01, 0x03, 0x12, 0x21, 0xFF):
        assert write_u8(node, 0.1, 0x2005, 0, value) == abort(0x2005, 0, 0x06090030)
    assert read(node, 0.2, 0x2005)[4] == 0x00


def test_mapping_object_reads_as_the_manual_prints_it_whatever_the_pdo_type() -> None:
    node = make()
    assert write_u8(node, 0.1, 0x2005, 0, 0x22) == ok(0x2005, 0)
    assert read(node, 0.2, 0x1A00, 0)[4] == 0x01
    assert read(node, 0.2, 0x1A00, 1)[4:] == struct.pack("<I", 0x60040020)


def test_pdo_type_survives_a_reset_only_when_stored() -> None:
    node = make()
    assert write_u8(node, 0.1, 0x2005, 0, 0x02) == ok(0x2005, 0)
    nmt(node, 0.2, 0x81, 1)
    assert read(node, 0.3, 0x2005)[4] == 0x00
    assert write_u8(node, 0.4, 0x2005, 0, 0x02) == ok(0x2005, 0)
    assert write_u32(node, 0.5, 0x1010, 1, 0x65766173) == ok(0x1010, 1)
    nmt(node, 0.6, 0x81, 1)
    assert read(node, 0.7, 0x2005)[4] == 0x02


# -- cams 6300h-6320h -----------------------------------------------------------------------------
def cam_state(node: SimNode, now: float) -> int:
    response = read(node, now, 0x6300, 1)
    assert response[:4] == bytes([0x4F, 0x00, 0x63, 0x01])
    return response[4]


def setup_cam(node: SimNode, low: int, high: int, *, enable: int = 1, polarity: int = 0) -> None:
    assert write_u32(node, 0.1, 0x6310, 1, low) == ok(0x6310, 1)
    assert write_u32(node, 0.1, 0x6320, 1, high) == ok(0x6320, 1)
    assert write_u8(node, 0.1, 0x6302, 1, polarity) == ok(0x6302, 1)
    assert write_u8(node, 0.1, 0x6301, 1, enable) == ok(0x6301, 1)


def test_cam_is_active_between_low_and_high_limit_inclusive() -> None:
    node = make(position=5000)
    setup_cam(node, 4000, 6000)
    assert cam_state(node, 0.2) == 0x01
    node.motion.freeze(6000)
    assert cam_state(node, 0.3) == 0x01
    node.motion.freeze(6001)
    assert cam_state(node, 0.4) == 0x00
    node.motion.freeze(3999)
    assert cam_state(node, 0.5) == 0x00


def test_cam_state_follows_the_moving_position() -> None:
    node = make(speed=1000.0)  # ramp 0 -> up at 1000 counts/s
    setup_cam(node, 1000, 2000)
    assert cam_state(node, 0.5) == 0  # position 500
    assert cam_state(node, 1.5) == 1  # position 1500
    assert cam_state(node, 2.5) == 0  # position 2500


def test_cam_polarity_1_makes_an_active_cam_read_0() -> None:
    node = make(position=5000)
    setup_cam(node, 4000, 6000, polarity=1)
    assert cam_state(node, 0.2) == 0x00
    node.motion.freeze(7000)
    assert cam_state(node, 0.3) == 0x01


def test_disabled_cam_reads_0_whatever_the_position_and_polarity() -> None:
    node = make(position=5000)
    setup_cam(node, 4000, 6000, enable=0, polarity=1)
    assert cam_state(node, 0.2) == 0x00
    node.motion.freeze(9000)
    assert cam_state(node, 0.3) == 0x00


def test_cam_with_low_limit_above_high_limit_wraps_through_the_range_end() -> None:
    node = make(position=0x1FFFFF00)
    setup_cam(node, 0x1FFFF000, 0x100)
    assert cam_state(node, 0.2) == 1
    node.motion.freeze(0x80)
    assert cam_state(node, 0.3) == 1
    node.motion.freeze(0x1000)
    assert cam_state(node, 0.4) == 0


def test_cam_state_register_is_read_only() -> None:
    node = make()
    assert write_u8(node, 0.1, 0x6300, 1, 1) == abort(0x6300, 1, 0x06010002)


# -- 1016h heartbeat consumer ---------------------------------------------------------------------
MASTER = 0x7F
CONSUMER_100MS = (MASTER << 16) | 100  # bits 16-23 node id, bits 0-15 time in ms


def emcy_frames(frames: list[can.Message]) -> list[bytes]:
    return [bytes(f.data) for f in frames if f.arbitration_id == 0x081]


def run(node: SimNode, start: float, stop: float, step: float = 0.001) -> list[can.Message]:
    out: list[can.Message] = []
    steps = round((stop - start) / step)
    for i in range(steps + 1):
        out += node.tick(start + i * step)
    return out


def test_consumer_waits_for_the_first_heartbeat_before_monitoring() -> None:
    node = make()
    assert write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS) == ok(0x1016, 1)
    assert emcy_frames(run(node, 0.1, 1.0)) == []


def test_missing_master_heartbeat_raises_emcy_8130h_with_communication_error() -> None:
    node = make()
    assert write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS) == ok(0x1016, 1)
    node.handle(frame(0x700 + MASTER, 0x05), 1.000)
    assert emcy_frames(run(node, 1.001, 1.100)) == []  # exactly 100 ms: still in time
    frames = emcy_frames(run(node, 1.101, 1.120))
    # 81h (80h + node 1): code 8130h LE, 1001h = bit 0 generic | bit 4 communication
    assert frames == [bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])]
    assert read(node, 1.2, 0x1001) == bytes([0x4F, 0x01, 0x10, 0x00, 0x11, 0, 0, 0])
    assert read(node, 1.2, 0x1003, 0)[4] == 1
    assert read(node, 1.2, 0x1003, 1)[4:6] == bytes([0x30, 0x81])
    assert emcy_frames(run(node, 1.121, 1.5)) == []  # signalled once


def test_heartbeat_back_sends_error_reset_and_clears_the_error_register() -> None:
    node = make()
    write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS)
    node.handle(frame(0x700 + MASTER, 0x05), 1.0)
    run(node, 1.0, 1.2)
    out = node.handle(frame(0x700 + MASTER, 0x05), 1.3)
    assert emcy_frames(out) == [bytes(8)]
    assert read(node, 1.31, 0x1001)[4] == 0x00
    # monitoring goes on from the new heartbeat
    assert emcy_frames(run(node, 1.301, 1.400)) == []
    assert len(emcy_frames(run(node, 1.401, 1.45))) == 1


def test_heartbeats_of_other_nodes_do_not_feed_the_consumer() -> None:
    node = make()
    write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS)
    node.handle(frame(0x700 + MASTER, 0x05), 1.0)
    for i in range(10):
        node.handle(frame(0x700 + 0x10, 0x05), 1.0 + i * 0.02)
    assert len(emcy_frames(run(node, 1.0, 1.2))) == 1


def test_heartbeat_loss_does_not_change_the_nmt_state() -> None:
    node = make()
    write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS)
    nmt(node, 0.1, 0x01, 1)
    node.handle(frame(0x700 + MASTER, 0x05), 1.0)
    run(node, 1.0, 1.2)
    assert int(node.nmt_state) == 0x05


def test_consumer_time_0_switches_monitoring_off_and_clears_a_pending_error() -> None:
    node = make()
    write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS)
    node.handle(frame(0x700 + MASTER, 0x05), 1.0)
    run(node, 1.0, 1.2)
    out = node.handle(frame(0x601, 0x23, 0x16, 0x10, 0x01, 0, 0, 0, 0), 1.3)
    assert only(out, 0x581) == ok(0x1016, 1)
    assert emcy_frames(out) == [bytes(8)]
    assert emcy_frames(run(node, 1.3, 2.0)) == []


def test_reset_node_disarms_the_consumer_until_the_next_heartbeat() -> None:
    node = make()
    write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS)
    write_u32(node, 0.1, 0x1010, 1, 0x65766173)
    node.handle(frame(0x700 + MASTER, 0x05), 1.0)
    run(node, 1.0, 1.2)
    nmt(node, 1.3, 0x81, 1)
    assert read(node, 1.31, 0x1001)[4] == 0x00
    assert read(node, 1.31, 0x1016, 1)[4:] == struct.pack("<I", CONSUMER_100MS)
    assert emcy_frames(run(node, 1.31, 2.0)) == []


# -- 2101h / 2100h node id and bit rate ----------------------------------------------------------
def test_node_number_written_without_store_is_lost_at_reset() -> None:
    node = make()
    assert write_u8(node, 0.1, 0x2101, 0, 5) == ok(0x2101, 0)
    assert read(node, 0.2, 0x2101)[4] == 5  # reads back the new value ...
    assert node.node_id == 1  # ... but the node id changes only after store + reset
    out = nmt(node, 0.3, 0x81, 1)
    assert only(out, 0x701) == b"\x00"
    assert read(node, 0.4, 0x2101)[4] == 1


def test_node_number_takes_effect_after_store_and_nmt_reset_node() -> None:
    node = make()
    assert write_u8(node, 0.1, 0x2101, 0, 5) == ok(0x2101, 0)
    assert sdo(node, 0.2, 0x23, 0x10, 0x10, 0x01, *SAVE) == ok(0x1010, 1)
    assert node.node_id == 1
    out = nmt(node, 0.3, 0x81, 1)
    assert only(out, 0x705) == b"\x00"  # boot-up with the new node id
    assert node.node_id == 5
    assert node.handle(frame(0x601, 0x40, 0x04, 0x60, 0, 0, 0, 0, 0), 0.4) == []
    assert read(node, 0.4, 0x1800, 1)[4:] == struct.pack("<I", 0x185)
    assert read(node, 0.4, 0x1801, 1)[4:] == struct.pack("<I", 0x285)
    assert read(node, 0.4, 0x1014, 0)[4:] == struct.pack("<I", 0x85)
    assert read(node, 0.4, 0x2101)[4] == 5


def test_stored_node_number_survives_a_power_cycle() -> None:
    store = PersistentStore()
    node = make(store=store)
    write_u8(node, 0.1, 0x2101, 0, 0x20)
    write_u32(node, 0.2, 0x1010, 1, 0x65766173)
    out = node.power_cycle(1.0)
    assert only(out, 0x720) == b"\x00"
    again = SimNode(load_profile("posi_plus"), 1, store=store)
    assert only(again.power_on(0.0), 0x720) == b"\x00"


def test_reset_communication_does_not_apply_a_stored_node_number() -> None:
    node = make()
    write_u8(node, 0.1, 0x2101, 0, 5)
    write_u32(node, 0.2, 0x1010, 1, 0x65766173)
    out = nmt(node, 0.3, 0x82, 1)
    assert only(out, 0x701) == b"\x00"


def test_restore_defaults_brings_back_node_1_after_reset() -> None:
    node = make()
    write_u8(node, 0.1, 0x2101, 0, 5)
    write_u32(node, 0.2, 0x1010, 1, 0x65766173)
    nmt(node, 0.3, 0x81, 1)
    assert node.node_id == 5
    assert sdo(node, 0.4, 0x23, 0x11, 0x10, 0x01, *LOAD) == ok(0x1011, 1)
    assert node.node_id == 5  # only after the reset
    out = nmt(node, 0.5, 0x81, 5)
    assert only(out, 0x701) == b"\x00"
    assert read(node, 0.6, 0x2101)[4] == 1
    assert read(node, 0.6, 0x2100)[4] == 1


@pytest.mark.parametrize("value", [0, 128, 255])
def test_node_numbers_outside_1_to_127_are_refused(value: int) -> None:
    node = make()
    assert write_u8(node, 0.1, 0x2101, 0, value) == abort(0x2101, 0, 0x06090030)


def test_bit_rate_code_takes_effect_after_store_and_reset() -> None:
    node = make()
    beh = node.feature("node_id_object")
    assert beh is not None
    assert beh.bitrate_kbps == 20  # factory 2100h = 1
    assert write_u8(node, 0.1, 0x2100, 0, 4) == ok(0x2100, 0)
    assert beh.bitrate_kbps == 20
    assert write_u8(node, 0.1, 0x2100, 0, 8) == abort(0x2100, 0, 0x06090030)
    write_u32(node, 0.2, 0x1010, 1, 0x65766173)
    nmt(node, 0.3, 0x81, 0)
    assert beh.bitrate_kbps == 125
    assert read(node, 0.4, 0x2100)[4] == 4


def test_node_started_with_another_id_reads_it_in_2101h() -> None:
    node = make(node_id=9)
    assert read(node, 0.1, 0x2101)[4] == 9


# -- POSI+ SF -------------------------------------------------------------------------------------
def test_sf_node_number_6101h_and_its_c5_alias_take_effect_after_store_and_reset() -> None:
    node = make("posi_sf")
    assert write_u16(node, 0.1, 0x6101, 0, 7) == ok(0x6101, 0)
    assert read(node, 0.1, 0x3000)[4] == 7  # "C5 Node number" follows
    write_u32(node, 0.2, 0x1010, 1, 0x65766173)
    out = nmt(node, 0.3, 0x81, 1)
    assert only(out, 0x707) == b"\x00"
    assert write_u8(node, 0.4, 0x3000, 0, 200) == abort(0x3000, 0, 0x06090030)


def test_sf_has_no_pdo_type_and_no_cams() -> None:
    node = make("posi_sf")
    assert {b.feature for b in node.features} <= {"heartbeat_consumer", "node_id_object"}
    assert write_u8(node, 0.1, 0x2005, 0, 2) == abort(0x2005, 0, 0x06020000)
    assert read(node, 0.1, 0x6300, 1) == abort(0x6300, 1, 0x06020000)


def test_sf_consumes_the_master_heartbeat_too() -> None:
    node = make("posi_sf")
    write_u32(node, 0.1, 0x1016, 1, CONSUMER_100MS)
    node.handle(frame(0x700 + MASTER, 0x05), 1.0)
    assert emcy_frames(run(node, 1.0, 1.2)) == [bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0])]
