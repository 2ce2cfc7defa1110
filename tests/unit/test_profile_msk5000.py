"""The SIKO MSK5000CAN profile (canopen_gateway/profiles/msk5000.*) against its manual (seed 001).

The facts below are copied from the manual (section numbers in comments) so that the test runs
without the manual. Imports: canopen_gateway.profiles, canopen (data type constants) and pytest only.
"""

from __future__ import annotations

import canopen.objectdictionary.datatypes as dt
import pytest

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles import PROFILE_DIR, import_eds, load_profile

U8, U16, U32 = dt.UNSIGNED8, dt.UNSIGNED16, dt.UNSIGNED32
I16, I32, VS = dt.INTEGER16, dt.INTEGER32, dt.VISIBLE_STRING

# Manual 4.6.1 Table 10 and the object descriptions 4.6.1.1-4.6.1.40:
# (index, sub, data type, access). Deviations decided in the profile notes are marked.
OBJECTS: list[tuple[int, int, int, str]] = [
    (0x1000, 0, U32, "ro"),
    (0x1001, 0, U8, "ro"),
    (0x1002, 0, U32, "ro"),
    (0x1003, 0, U8, "rw"),
    *[(0x1003, s, U32, "ro") for s in range(1, 9)],
    (0x1005, 0, U32, "rw"),
    (0x1008, 0, VS, "const"),
    (0x1009, 0, VS, "const"),
    (0x100A, 0, VS, "const"),
    (0x100C, 0, U16, "rw"),
    (0x100D, 0, U8, "rw"),
    (0x1010, 0, U8, "ro"),
    *[(0x1010, s, U32, "rw") for s in range(1, 5)],
    (0x1011, 0, U8, "ro"),
    *[(0x1011, s, U32, "rw") for s in range(1, 5)],
    (0x1014, 0, U32, "rw"),
    (0x1015, 0, U16, "rw"),
    (0x1017, 0, U16, "rw"),
    (0x1018, 0, U8, "ro"),
    *[(0x1018, s, U32, "ro") for s in range(1, 5)],
    (0x1200, 0, U8, "ro"),
    (0x1200, 1, U32, "ro"),
    (0x1200, 2, U32, "ro"),
    (0x1800, 0, U8, "ro"),
    (0x1800, 1, U32, "rw"),
    (0x1800, 2, U8, "rw"),
    (0x1800, 3, U16, "const"),
    (0x1800, 5, U16, "rw"),
    (0x1801, 0, U8, "ro"),
    (0x1801, 1, U32, "rw"),
    (0x1801, 2, U8, "rw"),
    (0x1801, 3, U16, "ro"),
    (0x1801, 5, U16, "ro"),
    (0x1A00, 0, U8, "rw"),
    (0x1A00, 1, U32, "rw"),  # table says ro; 4.3.1.2 writes it (notes)
    (0x1A00, 2, U32, "rw"),  # table says UNSIGNED 16 with a 32-bit value (notes)
    (0x1A01, 0, U8, "rw"),
    (0x1A01, 1, U32, "rw"),
    (0x1A01, 2, U32, "rw"),
    (0x5115, 0, U8, "rw"),
    (0x5122, 0, U8, "ro"),
    *[(0x5122, s, U8, "ro") for s in range(1, 5)],
    (0x5F09, 0, U8, "ro"),
    (0x5F0A, 0, U8, "ro"),
    (0x5F0A, 1, U8, "rw"),
    (0x5F0A, 2, U8, "rw"),
    (0x5FFA, 0, I16, "rw"),
    (0x6000, 0, U16, "rw"),
    (0x6003, 0, I32, "rw"),
    (0x6004, 0, I32, "ro"),
    (0x6005, 0, U8, "ro"),
    (0x6005, 1, U32, "rw"),
    (0x6005, 2, U32, "ro"),
    (0x6030, 0, U8, "ro"),
    (0x6030, 1, I16, "ro"),
    (0x6200, 0, U16, "rw"),
    (0x6500, 0, U16, "ro"),
    (0x6501, 0, U32, "ro"),
    (0x6502, 0, U16, "ro"),
    (0x6507, 0, U32, "ro"),
    (0x6508, 0, U32, "ro"),
    (0x6509, 0, U32, "ro"),
    (0x650A, 0, U8, "ro"),
    (0x650A, 1, U32, "ro"),
    (0x650A, 2, U32, "ro"),
    (0x650A, 3, I32, "ro"),
    (0x650B, 0, U32, "ro"),
]

# Manual: object -> PDO mapping "Yes" (6004h, 6030h:01) plus 5122h:01/02 mapped by the
# example of 4.3.1.2.
MAPPABLE = {(0x6004, 0), (0x6030, 1), (0x5122, 1), (0x5122, 2)}

# Manual 4.5.1 Table 9.
EMCY_CODES = [0x0000, 0x8120, 0x8140, 0xFF10, 0xFF12, 0xFF13, 0xFF14, 0xFF15, 0xFF16, 0xFF17]


@pytest.fixture(scope="module")
def od():
    return import_eds(PROFILE_DIR / "msk5000.eds")


@pytest.fixture(scope="module")
def lp():
    return load_profile("msk5000")


def _var(od, index: int, sub: int):
    entry = od[index]
    return entry if sub == 0 and not hasattr(entry, "subindices") else entry[sub]


def test_eds_imports_without_any_warning(od) -> None:
    assert 0x1000 in od


@pytest.mark.parametrize(("index", "sub", "data_type", "access"), OBJECTS)
def test_every_manual_object_exists_with_its_type_and_access(
    od, index: int, sub: int, data_type: int, access: str
) -> None:
    var = _var(od, index, sub)
    assert var.data_type == data_type, f"{ObjRef(index, sub)} data type"
    assert var.access_type == access, f"{ObjRef(index, sub)} access"
    assert var.pdo_mappable == ((index, sub) in MAPPABLE), f"{ObjRef(index, sub)} PDOMapping"


def test_unused_tpdo_sub_index_4_does_not_exist(od) -> None:
    # 4.6.1.18/19: "Sub-index 04h (is not used; access generates an error message)"
    for index in (0x1800, 0x1801):
        with pytest.raises(KeyError):
            od[index][4]


def test_tpdo_mapping_objects_have_eight_entries_for_remapping(od) -> None:
    # 4.3.1.2: up to 8 bytes per PDO; the example writes 1A00h:03
    for index in (0x1A00, 0x1A01):
        for sub in range(1, 9):
            assert od[index][sub].access_type == "rw"


def test_defaults_match_the_manual(od) -> None:
    assert od[0x1000].default == 0x00010196  # 4.6.1.1
    assert od[0x1008].default == "MSK5000CAN"  # 4.6.1.6
    assert od[0x1009].default == "V100"  # 4.6.1.7
    assert od[0x100A].default == "V001"  # 4.6.1.8 (notes)
    assert od[0x1017].default == 0  # 4.6.1.15
    assert od[0x1018][1].default == 0x195  # 4.6.1.16 SIKO
    assert od[0x1800][2].default == 0xFE  # 4.6.1.18
    assert od[0x1800][5].default == 0
    assert od[0x1801][2].default == 1  # 4.6.1.19
    assert od[0x1A00][0].default == 2  # 4.6.1.20
    assert od[0x1A00][1].default == 0x60040020
    assert od[0x1A00][2].default == 0x60300110
    assert od[0x1A01][1].default == 0x60040020
    assert od[0x1A01][2].default == 0x60300110
    assert od[0x5115].default == 0  # 4.6.1.22
    assert od[0x5122][3].default == 0x83  # 4.6.1.23
    assert od[0x5F0A][1].default == 1  # 4.6.1.25
    assert od[0x5F0A][2].default == 4  # 250 kbit/s by the value table (notes)
    assert od[0x5FFA].default == 0  # 4.6.1.26 alarm off
    assert od[0x6000].default == 4  # 4.6.1.27
    assert od[0x6005][2].default == 100  # 0.01 mm/s x 100
    assert od[0x6200].default == 0  # 4.6.1.32
    assert od[0x6500].default == 4
    assert od[0x6501].default == 5000
    assert od[0x6507].default == 0x00010302  # byte table (notes)
    assert od[0x650A][2].default == 0x80000000
    assert od[0x650A][3].default == 0x7FFFFFFF


def test_node_id_relative_cob_ids_resolve_for_a_node(od) -> None:
    od5 = import_eds(PROFILE_DIR / "msk5000.eds", node_id=5)
    assert od5[0x1014].default == 0x85
    assert od5[0x1200][1].default == 0x605
    assert od5[0x1200][2].default == 0x585
    assert od5[0x1800][1].default == 0x185
    assert od5[0x1801][1].default == 0x285
    assert od[0x1800][1].default_raw == "$NODEID+0x180"


def test_device_info_declares_vendor_bitrates_and_two_tpdos(od) -> None:
    info = od.device_information
    assert info.vendor_number == 0x195
    assert info.nr_of_TXPDO == 2
    assert info.nr_of_RXPDO == 0
    assert not info.LSS_supported
    # 5F0Ah:02: 50, (100), 125, 250, 500, 1000 kBaud; CiA 306 has no 100 kbit/s key
    assert info.allowed_baudrates == {50_000, 125_000, 250_000, 500_000, 1_000_000}


def test_profile_loads_with_factory_settings(lp) -> None:
    p = lp.profile
    assert p.family == "msk5000"
    assert p.device_type == 0x00010196
    assert p.factory.node_id == 1
    assert p.factory.bitrate_kbps == 250
    assert {"remappable_tpdo", "referencing", "speed_alarm"} <= set(p.features)


def test_default_tpdos_match_the_mapping_tables(lp) -> None:
    tpdos, rpdos = lp.profile.layout()
    assert rpdos == []
    t1, t2 = tpdos
    # 4.3.1.1 Table 5 / 1800h / 1A00h: 180h + node, async (FEh), position bytes 0-3, speed 4-5
    assert (t1.number, t1.cob_id, t1.transmission_type, t1.event_timer_ms) == (1, 0x180, 254, 0)
    assert [(str(e.object), e.bits) for e in t1.mapping] == [("0x6004:00", 32), ("0x6030:01", 16)]
    assert t1.length == 6
    # 1801h / 1A01h: 280h + node, every SYNC
    assert (t2.number, t2.cob_id, t2.transmission_type) == (2, 0x280, 1)
    assert [(str(e.object), e.bits) for e in t2.mapping] == [("0x6004:00", 32), ("0x6030:01", 16)]
    assert t2.length == 6


def test_profile_mapping_matches_eds_mapping_defaults(lp) -> None:
    for pdo, index in zip(lp.profile.tpdos, (0x1A00, 0x1A01), strict=True):
        assert lp.od[index][0].default == len(pdo.mapping)
        for sub, e in enumerate(pdo.mapping, start=1):
            assert (
                lp.od[index][sub].default == (e.object.index << 16) | (e.object.sub << 8) | e.bits
            )


def test_emcy_codes_of_the_manual_are_present(lp) -> None:
    assert sorted(lp.profile.emcy) == EMCY_CODES
    assert lp.profile.emcy[0xFF12] == "Manufacturer specific: Speed error"


def test_remapping_procedure_is_described_step_by_step(lp) -> None:
    f = lp.profile.features["remappable_tpdo"]
    assert [s["step"] for s in f["procedure"]] == [1, 2, 3, 4, 5, 6]
    assert f["procedure"][1]["example_frame"] == "601: 23 00 18 01 81 01 00 80"
    assert f["procedure"][5]["example_frame"] == "601: 23 00 18 01 81 01 00 00"
    assert f["example_mapping"] == ["0x6004:00/32", "0x5122:01/8", "0x5122:02/8"]
    for obj in f["mappable"]:
        assert lp.od_var(ObjRef.parse(obj)).pdo_mappable


def test_referencing_and_speed_alarm_objects_exist(lp) -> None:
    ref = lp.profile.features["referencing"]
    assert ref["command"] == "0x5115:00" and ref["command_value"] == 1
    assert ref["not_referenced_flag"] == {"object": "0x5122:01", "bit": 1}
    alarm = lp.profile.features["speed_alarm"]
    assert alarm["threshold"] == "0x5FFA:00" and alarm["emcy_code"] == 0xFF12
    for obj in (ref["command"], ref["calibration"], ref["offset"], alarm["threshold"]):
        assert lp.od_var(ObjRef.parse(obj)) is not None


def test_status_registers_name_every_documented_bit(lp) -> None:
    sys_bits = {b.bit: b.name for b in lp.profile.signal("sys_register").bits}
    assert sys_bits == {
        0: "tape_read_distance_error",
        1: "not_referenced",
        2: "speed_check_over_5m_s",
        4: "alignment_in_progress",
        5: "verify_error_not_aligned",
        6: "checksum_error",
    }
    assert len(lp.profile.signal("flag1_register").bits) == 8
    assert {b.bit for b in lp.profile.signal("error_register").bits} == {0, 4, 7}


def test_signals_scale_position_to_mm_and_speed_to_mm_per_s(lp) -> None:
    pos = lp.profile.signal("position")
    assert (str(pos.object), pos.type, pos.unit, pos.scale) == ("0x6004:00", "int32", "mm", 0.005)
    # 3.1 example: 340603 counts x 0.005 mm = 1703.015 mm
    assert 340603 * pos.scale == pytest.approx(1703.015)
    speed = lp.profile.signal("speed")
    assert (str(speed.object), speed.type, speed.unit) == ("0x6030:01", "int16", "mm/s")


def test_boot_defaults_enable_heartbeat_and_tpdo1_timer(lp) -> None:
    boot = lp.profile.boot
    assert boot.supervision == "heartbeat"
    assert boot.heartbeat_ms >= 10  # 1017h: 0 or 10..65535 ms
    writes = {str(w.object): w.value for w in boot.sdo}
    assert writes["0x1800:05"] > 0  # factory 0 would never send TPDO1


def test_notes_record_the_baud_rate_trap(lp) -> None:
    assert any("5F0Ah:02" in n and "250" in n for n in lp.profile.notes)
