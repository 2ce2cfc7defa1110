"""The simulated SIKO MSK5000CAN driven with raw CAN frames and a fake clock.

Frames are copied from the MSK5000CAN manual (seed 001): the TPDO remapping procedure 4.3.1.2,
the SDO examples 4.4.1.4, referencing 5115h (4.6.1.22) and the speed alarm 5FFAh (4.6.1.26).
Imports: python-can (Message), canopen_gateway.profiles, canopen_gateway.sim and pytest.
"""

from __future__ import annotations

import struct

import can
import pytest

from canopen_gateway.profiles import load_profile
from canopen_gateway.sim.features import feature_class
from canopen_gateway.sim.node import SimNode
from tests.helpers import frame

NODE = 1
SDO_RX, SDO_TX = 0x600 + NODE, 0x580 + NODE
EMCY = 0x080 + NODE
TPDO1, TPDO2 = 0x180 + NODE, 0x280 + NODE


def hexs(msg: can.Message) -> str:
    return bytes(msg.data).hex(" ").upper()


class Bench:
    """One simulated MSK5000CAN, node 1, and a fake clock in seconds."""

    def __init__(self, motion: dict | None = None) -> None:
        self.node = SimNode(
            load_profile("msk5000"), NODE, motion=motion or {"kind": "hold", "hold": 1000}
        )
        self.now = 0.0
        self.boot = self.node.power_on(self.now)

    def send(self, cob_id: int, hex_bytes: str) -> list[can.Message]:
        return self.node.handle(frame(cob_id, hex_bytes), self.now)

    def sdo(self, request: str) -> str:
        """The one SDO response (581h) to ``request`` on 601h, as upper-case hex bytes."""
        out = [m for m in self.send(SDO_RX, request) if m.arbitration_id == SDO_TX]
        assert len(out) == 1, out
        return hexs(out[0])

    def nmt(self, command: int) -> list[can.Message]:
        return self.send(0x000, f"{command:02X} {NODE:02X}")

    def advance(self, seconds: float) -> list[can.Message]:
        self.now += seconds
        return self.node.tick(self.now)


def abort(index: int, sub: int, code: int) -> str:
    return struct.pack("<BHBI", 0x80, index, sub, code).hex(" ").upper()


# Manual 4.3.1.2: "Example of changing a PDO1 mapping", node 1h, request -> response
REMAP_SEQUENCE = [
    ("23 00 18 01 81 01 00 80", "60 00 18 01 00 00 00 00"),  # TPDO1 inactive, 80000181h
    ("23 00 1A 00 00 00 00 00", "60 00 1A 00 00 00 00 00"),  # 1A00.0h = 0
    ("23 00 1A 01 20 00 04 60", "60 00 1A 01 00 00 00 00"),  # 60040020h position 32 bit
    ("23 00 1A 02 08 01 22 51", "60 00 1A 02 00 00 00 00"),  # 51220108h sys register
    ("23 00 1A 03 08 02 22 51", "60 00 1A 03 00 00 00 00"),  # 51220208h flag 0 register
    ("23 00 1A 00 03 00 00 00", "60 00 1A 00 00 00 00 00"),  # 1A00.0h = 3
    ("23 00 18 01 81 01 00 00", "60 00 18 01 00 00 00 00"),  # TPDO1 active, 00000181h
]


def test_sim_features_are_registered_under_their_feature_names() -> None:
    for feature in ("remappable_tpdo", "referencing", "speed_alarm"):
        cls = feature_class(feature)
        assert cls is not None and cls.feature == feature
    bench = Bench()
    assert {b.feature for b in bench.node.features} >= {
        "remappable_tpdo",
        "referencing",
        "speed_alarm",
    }


def test_boots_pre_operational_with_boot_up_frame() -> None:
    bench = Bench()
    assert [(m.arbitration_id, hexs(m)) for m in bench.boot] == [(0x701, "00")]  # 4.2.2


# -- 4.3.1.2 variable TPDO mapping ---------------------------------------------------------


def test_manual_remapping_sequence_is_answered_byte_for_byte() -> None:
    bench = Bench()
    for request, response in REMAP_SEQUENCE:
        assert bench.sdo(request) == response, request
    assert bench.sdo("40 00 1A 00 00 00 00 00") == "4F 00 1A 00 03 00 00 00"
    assert bench.sdo("40 00 1A 02 00 00 00 00") == "43 00 1A 02 08 01 22 51"
    assert bench.sdo("40 00 18 01 00 00 00 00") == "43 00 18 01 81 01 00 00"


def test_remapped_tpdo1_carries_position_sys_register_and_flag0() -> None:
    bench = Bench()
    for request, _ in REMAP_SEQUENCE:
        bench.sdo(request)
    assert bench.sdo("2B 00 62 00 0A 00 00 00") == "60 00 62 00 00 00 00 00"  # 6200h = 10 ms
    bench.nmt(0x01)
    tpdo = [m for m in bench.advance(0.001) if m.arbitration_id == TPDO1]
    # not referenced yet: position 0, sys register bit 1 "Encoder not referenced", flag 0 = 00h
    assert [hexs(m) for m in tpdo] == ["00 00 00 00 02 00"]
    # referenced at calibration value 510 (01FEh): position FE 01 00 00, sys register 00h
    bench.nmt(0x80)
    bench.sdo("23 03 60 00 FE 01 00 00")
    bench.sdo("2F 15 51 00 01 00 00 00")
    bench.nmt(0x01)
    tpdo = [m for m in bench.advance(0.001) if m.arbitration_id == TPDO1]
    assert [hexs(m) for m in tpdo] == ["FE 01 00 00 00 00"]


def test_tpdo2_keeps_its_default_layout_after_tpdo1_is_remapped() -> None:
    bench = Bench()
    for request, _ in REMAP_SEQUENCE:
        bench.sdo(request)
    bench.nmt(0x01)
    sync = [m for m in bench.send(0x080, "") if m.arbitration_id == TPDO2]
    assert [hexs(m) for m in sync] == ["00 00 00 00 00 00"]  # position 32 bit + speed 16 bit


def test_remapping_in_operational_is_refused_with_device_state_abort() -> None:
    bench = Bench()
    bench.nmt(0x01)
    # 4.2.1.1: COB ID and TPDO mapping cannot be changed in OPERATIONAL
    assert bench.sdo("23 00 18 01 81 01 00 80") == abort(0x1800, 1, 0x08000022)
    assert bench.sdo("23 00 1A 00 00 00 00 00") == abort(0x1A00, 0, 0x08000022)
    assert bench.sdo("40 00 18 01 00 00 00 00") == "43 00 18 01 81 01 00 00"


def test_mapping_written_while_the_pdo_is_valid_is_refused() -> None:
    bench = Bench()
    # step 2 skipped: 1A00.0h = 0 while TPDO1 is valid
    assert bench.sdo("23 00 1A 00 00 00 00 00") == abort(0x1A00, 0, 0x08000022)
    assert bench.sdo("23 00 1A 01 20 00 04 60") == abort(0x1A00, 1, 0x08000022)
    assert bench.sdo("40 00 1A 00 00 00 00 00") == "4F 00 1A 00 02 00 00 00"


def test_mapping_entry_written_while_mapping_is_enabled_is_refused() -> None:
    bench = Bench()
    bench.sdo(REMAP_SEQUENCE[0][0])  # step 2 done, step 3 skipped
    assert bench.sdo("23 00 1A 01 20 00 04 60") == abort(0x1A00, 1, 0x08000022)
    feature = bench.node.feature("remappable_tpdo")
    assert feature.state(1) == "deactivated"


def test_cob_id_cannot_change_while_the_pdo_is_valid() -> None:
    bench = Bench()
    # manual 4.1: "Via bit 31 = 1b, the COB ID must first be invalidated before it can be changed"
    assert bench.sdo("23 00 18 01 82 01 00 00") == abort(0x1800, 1, 0x08000022)
    assert bench.sdo("23 00 18 01 81 01 00 80") == "60 00 18 01 00 00 00 00"
    assert bench.sdo("23 00 18 01 82 01 00 80") == "60 00 18 01 00 00 00 00"
    assert bench.sdo("23 00 18 01 82 01 00 00") == "60 00 18 01 00 00 00 00"


def test_unmappable_or_oversized_entries_are_refused() -> None:
    bench = Bench()
    bench.sdo(REMAP_SEQUENCE[0][0])
    bench.sdo(REMAP_SEQUENCE[1][0])
    assert bench.node.feature("remappable_tpdo").state(1) == "mapping_disabled"
    # 6000h operating parameters: PDO mapping "No"
    assert bench.sdo("23 00 1A 01 10 00 00 60") == abort(0x1A00, 1, 0x06040041)
    # 7000h does not exist
    assert bench.sdo("23 00 1A 01 20 00 00 70") == abort(0x1A00, 1, 0x06040041)
    # 5122h:01 is 8 bits, 16 requested
    assert bench.sdo("23 00 1A 01 10 01 22 51") == abort(0x1A00, 1, 0x06040041)
    # three entries of 32 + 32 + 16 bits exceed 8 bytes when enabled
    bench.sdo("23 00 1A 01 20 00 04 60")
    bench.sdo("23 00 1A 02 20 00 04 60")
    bench.sdo("23 00 1A 03 10 01 30 60")
    assert bench.sdo("23 00 1A 00 03 00 00 00") == abort(0x1A00, 0, 0x06040042)
    assert bench.sdo("23 00 1A 00 09 00 00 00") == abort(0x1A00, 0, 0x06040042)
    assert bench.sdo("23 00 1A 00 02 00 00 00") == "60 00 1A 00 00 00 00 00"


def test_oversized_expedited_write_with_nonzero_surplus_is_not_accepted() -> None:
    bench = Bench()
    bench.sdo(REMAP_SEQUENCE[0][0])
    # 23h to the 8-bit 1A00h:00 with data in byte 5: a length error (CiA 301 06070010h)
    assert bench.sdo("23 00 1A 00 00 01 00 00") == abort(0x1A00, 0, 0x06070010)


# -- 5115h referencing -----------------------------------------------------------------------


def test_position_is_not_available_before_referencing() -> None:
    bench = Bench()
    assert bench.sdo("40 15 51 00 00 00 00 00") == "4F 15 51 00 00 00 00 00"  # 5115h = 0
    assert bench.sdo("40 04 60 00 00 00 00 00") == abort(0x6004, 0, 0x08000024)
    assert bench.sdo("40 22 51 01 00 00 00 00") == "4F 22 51 01 02 00 00 00"  # bit 1 set


def test_referencing_sets_position_to_the_calibration_value() -> None:
    bench = Bench(motion={"kind": "ramp", "min": 0, "max": 1_000_000, "speed": 1000})
    bench.now = 2.0  # measurement 2000 counts
    assert bench.sdo("23 03 60 00 FE 01 00 00") == "60 03 60 00 00 00 00 00"  # 6003h = 510
    assert bench.sdo("2F 15 51 00 01 00 00 00") == "60 15 51 00 00 00 00 00"  # reference
    assert bench.sdo("40 15 51 00 00 00 00 00") == "4F 15 51 00 01 00 00 00"
    assert bench.sdo("40 04 60 00 00 00 00 00") == "43 04 60 00 FE 01 00 00"  # 510
    assert bench.sdo("40 09 65 00 00 00 00 00") == "43 09 65 00 D0 07 00 00"  # 6509h = 2000
    assert bench.sdo("40 22 51 01 00 00 00 00") == "4F 22 51 01 00 00 00 00"
    bench.now = 3.0  # moved 1000 counts further: position = 510 + 1000
    assert bench.sdo("40 04 60 00 00 00 00 00") == "43 04 60 00 E6 05 00 00"


def test_referencing_accepts_only_the_command_value_one() -> None:
    bench = Bench()
    assert bench.sdo("2F 15 51 00 00 00 00 00") == abort(0x5115, 0, 0x06090030)
    assert bench.sdo("2F 15 51 00 02 00 00 00") == abort(0x5115, 0, 0x06090030)


def test_reference_is_lost_on_reset_node_and_kept_on_reset_communication() -> None:
    bench = Bench()
    bench.sdo("2F 15 51 00 01 00 00 00")
    boot = bench.nmt(0x82)
    assert [(m.arbitration_id, hexs(m)) for m in boot] == [(0x701, "00")]
    assert bench.sdo("40 15 51 00 00 00 00 00") == "4F 15 51 00 01 00 00 00"
    assert bench.sdo("40 04 60 00 00 00 00 00") == "43 04 60 00 00 00 00 00"  # 6003h = 0
    bench.nmt(0x81)
    assert bench.sdo("40 15 51 00 00 00 00 00") == "4F 15 51 00 00 00 00 00"
    assert bench.sdo("40 04 60 00 00 00 00 00") == abort(0x6004, 0, 0x08000024)


def test_reference_is_lost_on_power_cycle_even_after_store() -> None:
    bench = Bench()
    bench.sdo("2F 15 51 00 01 00 00 00")
    assert bench.sdo("23 10 10 01 73 61 76 65") == "60 10 10 01 00 00 00 00"  # "save"
    bench.node.power_cycle(bench.now)
    assert bench.sdo("40 15 51 00 00 00 00 00") == "4F 15 51 00 00 00 00 00"


def test_sensor_error_loses_the_reference_and_sends_emcy_ff10() -> None:
    bench = Bench()
    bench.sdo("2F 15 51 00 01 00 00 00")
    assert bench.node.sensor_error(True, bench.now)
    emcy = [hexs(m) for m in bench.node.drain() if m.arbitration_id == EMCY]
    assert emcy == ["10 FF 81 00 00 00 00 00"]  # FF10h tape encoder, 1001h bits 0 and 7
    assert bench.sdo("40 15 51 00 00 00 00 00") == "4F 15 51 00 00 00 00 00"
    assert bench.sdo("40 22 51 01 00 00 00 00") == "4F 22 51 01 03 00 00 00"
    assert bench.sdo("2F 15 51 00 01 00 00 00") == abort(0x5115, 0, 0x08000024)
    bench.node.sensor_error(False, bench.now)
    emcy = [hexs(m) for m in bench.node.drain() if m.arbitration_id == EMCY]
    assert emcy == ["00 00 00 00 00 00 00 00"]
    assert bench.sdo("2F 15 51 00 01 00 00 00") == "60 15 51 00 00 00 00 00"


# -- 5FFAh speed alarm ------------------------------------------------------------------------


def _moving_at(mm_s: float) -> dict:
    # 5 um resolution: 200 counts per mm
    return {"kind": "ramp", "min": 0, "max": 100_000_000, "speed": mm_s * 200}


def test_speed_alarm_threshold_range_depends_on_resolution() -> None:
    bench = Bench()
    assert bench.sdo("2B FA 5F 00 31 00 00 00") == abort(0x5FFA, 0, 0x06090030)  # 49 mm/s
    assert bench.sdo("2B FA 5F 00 32 00 00 00") == "60 FA 5F 00 00 00 00 00"  # 50 mm/s
    assert bench.sdo("2B FA 5F 00 FF FF 00 00") == abort(0x5FFA, 0, 0x06090030)  # -1
    assert bench.sdo("2B FA 5F 00 00 00 00 00") == "60 FA 5F 00 00 00 00 00"  # 0 = off
    assert bench.sdo("23 05 60 01 10 27 00 00") == "60 05 60 01 00 00 00 00"  # 10 um
    assert bench.sdo("2B FA 5F 00 63 00 00 00") == abort(0x5FFA, 0, 0x06090030)  # 99 mm/s
    assert bench.sdo("2B FA 5F 00 64 00 00 00") == "60 FA 5F 00 00 00 00 00"  # 100 mm/s


def test_speed_alarm_sends_emcy_ff12_only_in_operational() -> None:
    bench = Bench(motion=_moving_at(200))
    bench.now = 1.0
    assert bench.sdo("40 30 60 01 00 00 00 00") == "4B 30 60 01 C8 00 00 00"  # 200 mm/s
    bench.sdo("2B FA 5F 00 64 00 00 00")  # alarm above 100 mm/s
    assert [m for m in bench.advance(0.001) if m.arbitration_id == EMCY] == []  # pre-op
    bench.nmt(0x01)
    emcy = [hexs(m) for m in bench.advance(0.001) if m.arbitration_id == EMCY]
    assert emcy == ["12 FF 81 00 00 00 00 00"]  # FF12h speed error, 1001h bits 0 and 7
    assert [m for m in bench.advance(0.001) if m.arbitration_id == EMCY] == []  # once
    assert bench.sdo("40 01 10 00 00 00 00 00") == "4F 01 10 00 81 00 00 00"
    # threshold raised above the speed: cleared with 0000h
    out = bench.send(SDO_RX, "2B FA 5F 00 2C 01 00 00")  # 300 mm/s
    emcy = [hexs(m) for m in out + bench.advance(0.001) if m.arbitration_id == EMCY]
    assert emcy == ["00 00 00 00 00 00 00 00"]


def test_speed_alarm_clears_when_leaving_operational() -> None:
    bench = Bench(motion=_moving_at(200))
    bench.sdo("2B FA 5F 00 64 00 00 00")
    bench.nmt(0x01)
    bench.advance(0.5)
    emcy = [hexs(m) for m in bench.nmt(0x80) if m.arbitration_id == EMCY]
    assert emcy == ["00 00 00 00 00 00 00 00"]
    assert [m for m in bench.advance(0.001) if m.arbitration_id == EMCY] == []


def test_speed_alarm_off_sends_nothing() -> None:
    bench = Bench(motion=_moving_at(200))
    bench.nmt(0x01)
    assert [m for m in bench.advance(0.5) if m.arbitration_id == EMCY] == []


def test_hardware_speed_check_bit_above_5_m_s() -> None:
    bench = Bench(motion=_moving_at(6000))
    bench.now = 0.5
    assert bench.sdo("40 22 51 01 00 00 00 00") == "4F 22 51 01 06 00 00 00"  # bits 1 and 2
    slow = Bench(motion=_moving_at(4000))
    slow.now = 0.5
    assert slow.sdo("40 22 51 01 00 00 00 00") == "4F 22 51 01 02 00 00 00"


# -- 4.4.1.4 SDO examples ---------------------------------------------------------------------


def test_manual_example_expedited_read_of_6003h() -> None:
    bench = Bench()
    bench.sdo("23 03 60 00 FE 01 00 00")  # the example's current value 510d = 01FEh
    assert bench.sdo("40 03 60 00 00 00 00 00") == "43 03 60 00 FE 01 00 00"


def test_manual_example_expedited_write_of_6200h() -> None:
    bench = Bench()
    assert bench.sdo("2B 00 62 00 94 11 00 00") == "60 00 62 00 00 00 00 00"  # 4500d
    # 6200h is the event timer of TPDO1 (4.6.1.32)
    assert bench.sdo("40 00 18 05 00 00 00 00") == "4B 00 18 05 94 11 00 00"


def test_manual_example_segmented_read_of_1008h() -> None:
    bench = Bench()
    # The example announces 6 bytes (41h ... 06h) and sends 03h + "MSK5000"; the device name
    # 1008h is "MSK5000CAN" (4.6.1.6), served by CiA 301: 10 bytes in two segments, the
    # first carrying the example's 7 bytes (profile notes).
    assert bench.sdo("40 08 10 00 00 00 00 00") == "41 08 10 00 0A 00 00 00"
    assert bench.sdo("60 08 10 00 00 00 00 00") == "00 4D 53 4B 35 30 30 30"  # "MSK5000"
    assert bench.sdo("70 00 00 00 00 00 00 00") == "19 43 41 4E 00 00 00 00"  # "CAN", last


@pytest.mark.parametrize(
    ("index", "sub", "response"),
    [
        (0x1000, 0, "43 00 10 00 96 01 01 00"),  # 4.6.1.1 byte table
        (0x1018, 1, "43 18 10 01 95 01 00 00"),  # SIKO vendor id 195h
        (0x5F0A, 2, "4F 0A 5F 02 04 00 00 00"),  # bit rate code 4 (250 kBaud, notes)
        (0x1A01, 2, "43 01 1A 02 10 01 30 60"),  # 60300110h
    ],
)
def test_defaults_read_by_sdo(index: int, sub: int, response: str) -> None:
    bench = Bench()
    assert bench.sdo(f"40 {index & 0xFF:02X} {index >> 8:02X} {sub:02X} 00 00 00 00") == response


# -- 5F0Ah node id and baud rate --------------------------------------------------------------


def test_node_id_from_5f0a_is_taken_over_after_save_and_reset_node() -> None:
    bench = Bench()
    assert bench.sdo("2F 0A 5F 01 05 00 00 00") == "60 0A 5F 01 00 00 00 00"  # node id 5
    assert bench.sdo("2F 0A 5F 01 80 00 00 00") == abort(0x5F0A, 1, 0x06090030)  # 128
    assert bench.sdo("23 10 10 01 73 61 76 65") == "60 10 10 01 00 00 00 00"  # "save"
    boot = bench.nmt(0x81)
    assert [(m.arbitration_id, hexs(m)) for m in boot] == [(0x705, "00")]
    feature = bench.node.feature("node_id_object")
    assert feature is not None and feature.bitrate_kbps == 250  # code 4 (notes)
