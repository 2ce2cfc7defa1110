"""The AP05 profile and EDS follow the SIKO AP05 user manual (seeds file 004), object by object.

The facts below are copied from the manual's object tables (5.7.1 table 33 and 5.7.2.x), the PDO
tables (5.3.1 tables 25/26), the control/status word tables (5.3.2 table 27, 5.3.3 table 28) and
the EMCY table (5.5.1 table 31), so that the test runs without the manual.

Imports: canopen_gateway.profiles, canopen, struct. No I/O beyond reading the profile files.
"""

from __future__ import annotations

import configparser
import struct

import canopen
import pytest

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles import import_eds, load_profile
from canopen_gateway.profiles.schema import Pdo, Signal, default_cob_id

U8, U16, U32 = 0x0005, 0x0006, 0x0007
I16, I32, VIS = 0x0003, 0x0004, 0x0009

# (index, sub, data type, access, PDO-mappable) from manual 5.7.2.1 .. 5.7.2.66
MANUAL_OBJECTS: list[tuple[int, int, int, str, bool]] = [
    (0x1000, 0, U32, "ro", False),
    (0x1001, 0, U8, "ro", False),
    (0x1002, 0, U32, "ro", False),
    (0x1003, 0, U8, "rw", False),
    *[(0x1003, s, U32, "ro", False) for s in range(1, 9)],
    (0x1005, 0, U32, "rw", False),
    (0x1008, 0, VIS, "const", False),
    (0x1009, 0, VIS, "const", False),
    (0x100A, 0, VIS, "const", False),
    (0x100C, 0, U16, "rw", False),
    (0x100D, 0, U8, "rw", False),
    (0x1010, 0, U8, "ro", False),
    *[(0x1010, s, U32, "rw", False) for s in range(1, 5)],
    (0x1011, 0, U8, "ro", False),
    *[(0x1011, s, U32, "rw", False) for s in range(1, 5)],
    (0x1014, 0, U32, "rw", False),
    (0x1017, 0, U16, "rw", False),
    (0x1018, 0, U8, "ro", False),
    *[(0x1018, s, U32, "ro", False) for s in range(1, 5)],
    (0x1200, 0, U8, "ro", False),
    (0x1200, 1, U32, "ro", False),
    (0x1200, 2, U32, "ro", False),
    *[
        row
        for idx in (0x1400, 0x1401)
        for row in (
            (idx, 0, U8, "ro", False),
            (idx, 1, U32, "rw", False),
            (idx, 2, U8, "rw", False),
            (idx, 3, U16, "ro", False),
            (idx, 5, U16, "ro", False),
        )
    ],
    *[(idx, s, U8 if s == 0 else U32, "ro", False) for idx in (0x1600, 0x1601) for s in range(4)],
    (0x1800, 0, U8, "ro", False),
    (0x1800, 1, U32, "rw", False),
    (0x1800, 2, U8, "rw", False),
    (0x1800, 3, U16, "ro", False),
    (0x1800, 5, U16, "rw", False),
    (0x1801, 0, U8, "ro", False),
    (0x1801, 1, U32, "rw", False),
    (0x1801, 2, U8, "rw", False),
    (0x1801, 3, U16, "ro", False),
    (0x1801, 5, U16, "ro", False),
    *[(idx, s, U8 if s == 0 else U32, "ro", False) for idx in (0x1A00, 0x1A01) for s in range(4)],
    (0x2001, 0, I16, "rw", False),
    (0x2002, 0, U8, "rw", False),
    (0x2003, 0, U8, "rw", False),
    (0x2004, 0, U8, "rw", False),
    (0x2005, 0, U8, "ro", False),
    (0x2005, 1, U8, "rw", False),
    (0x2005, 2, U8, "rw", False),
    (0x2005, 3, U32, "rw", False),
    (0x5000, 0, U32, "ro", False),
    (0x5F09, 0, U8, "ro", False),
    (0x5F09, 1, U16, "rw", False),
    (0x5F09, 2, U8, "rw", False),
    (0x5F0A, 0, U8, "ro", False),
    *[(0x5F0A, s, U8, "rw", False) for s in range(1, 4)],
    (0x5F0B, 0, U8, "rw", False),
    (0x5F0C, 0, U16, "ro", True),
    (0x5F0D, 0, U8, "ro", False),
    (0x5F0D, 1, U32, "ro", False),
    (0x5F0D, 2, U8, "rw", False),
    (0x5F10, 0, U16, "rw", False),
    (0x5F11, 0, U8, "rw", False),
    (0x5F12, 0, U8, "ro", False),
    *[(0x5F12, s, U8, "rw", False) for s in range(1, 11)],
    (0x5F13, 0, U8, "ro", False),
    (0x5F13, 1, U8, "rw", False),
    (0x5F13, 2, U8, "rw", False),
    (0x5F14, 0, U16, "rw", False),
    (0x5F15, 0, U8, "rw", False),
    (0x5F16, 0, U8, "ro", False),
    (0x5F16, 1, U32, "ro", True),
    (0x5F16, 2, U16, "ro", True),
    (0x5F16, 3, U32, "ro", True),
    (0x5F16, 4, U16, "ro", True),
    (0x5F17, 0, U8, "ro", False),
    (0x5F17, 1, U32, "ro", False),
    (0x5F17, 2, U32, "ro", False),
    (0x5F17, 3, I32, "ro", False),
    (0x5F17, 4, U8, "ro", False),
    (0x5F17, 5, U32, "ro", False),
    (0x5F19, 0, U16, "ro", True),
    (0x5F1B, 0, U8, "ro", False),
    (0x5F1B, 1, U8, "ro", False),
    (0x5F1B, 2, U8, "rw", False),
    (0x5F1B, 3, U8, "rw", False),
    (0x5F1C, 0, U8, "rw", False),
    (0x5F1F, 0, U8, "rw", False),
    (0x5F21, 0, U8, "ro", False),
    (0x5F21, 1, U16, "rw", False),
    (0x5F21, 2, U8, "rw", False),
    (0x6000, 0, U16, "rw", False),
    (0x6001, 0, U32, "rw", False),
    (0x6002, 0, U32, "rw", False),
    (0x6003, 0, I32, "rw", False),
    (0x6004, 0, U32, "ro", True),
    (0x6200, 0, U16, "rw", False),
    (0x6500, 0, U16, "ro", False),
    (0x6501, 0, U32, "ro", False),
    (0x6502, 0, U32, "ro", False),
    (0x6503, 0, U16, "ro", False),
    (0x6504, 0, U16, "ro", False),
    (0x6505, 0, U16, "ro", False),
    (0x6506, 0, U16, "ro", False),
    (0x6507, 0, U32, "ro", False),
    (0x6508, 0, U32, "ro", False),
    (0x6509, 0, I32, "ro", False),
    (0x650A, 0, U8, "ro", False),
    *[(0x650A, s, I32, "ro", False) for s in range(1, 4)],
    (0x650B, 0, U32, "ro", False),
]

# Manual 5.7.1 table 33, "Overview of objects", in its order.
TABLE_33 = [
    0x1000, 0x1001, 0x1002, 0x1003, 0x1005, 0x1008, 0x1009, 0x100A, 0x100C, 0x100D, 0x1010,
    0x1011, 0x1014, 0x1017, 0x1018, 0x1200, 0x1400, 0x1401, 0x1600, 0x1601, 0x1800, 0x1801,
    0x1A00, 0x1A01, 0x2001, 0x2002, 0x2003, 0x2004, 0x2005, 0x5000, 0x5F09, 0x5F0A, 0x5F0B,
    0x5F0C, 0x5F0D, 0x5F10, 0x5F11, 0x5F12, 0x5F13, 0x5F14, 0x5F15, 0x5F16, 0x5F17, 0x5F19,
    0x5F1B, 0x5F1C, 0x5F1F, 0x5F21, 0x6000, 0x6001, 0x6002, 0x6003, 0x6004, 0x6200, 0x6500,
    0x6501, 0x6502, 0x6503, 0x6504, 0x6505, 0x6506, 0x6507, 0x6508, 0x6509, 0x650A, 0x650B,
]  # fmt: skip

# Sub-indices the manual says do not exist ("access attempt generates error message").
ABSENT_SUBS = [(0x1400, 4), (0x1401, 4), (0x1800, 4), (0x1800, 6), (0x1801, 4), (0x1801, 6)]

# Factory defaults from the object tables (with node id 125 where "+ Node-ID").
FACTORY_NODE_ID = 125
DEFAULTS_AT_NODE_125: dict[tuple[int, int], int | str] = {
    (0x1000, 0): 0x00050196,
    (0x1005, 0): 0x80,
    (0x1008, 0): "AP05",
    (0x100C, 0): 0,
    (0x100D, 0): 0,
    (0x1014, 0): 0x80 + 125,
    (0x1017, 0): 0,
    (0x1018, 1): 0x195,
    (0x1018, 2): 0xFFFFFFFF,
    (0x1200, 1): 0x600 + 125,
    (0x1200, 2): 0x580 + 125,
    (0x1400, 1): 0x200 + 125,
    (0x1400, 2): 0xFF,
    (0x1401, 1): 0x300 + 125,
    (0x1401, 2): 0xFF,
    (0x1600, 0): 3,
    (0x1600, 1): 0x5F160320,
    (0x1600, 2): 0x5F160410,
    (0x1600, 3): 0x5F0C0010,
    (0x1601, 1): 0x5F160120,
    (0x1601, 2): 0x5F160210,
    (0x1601, 3): 0x5F0C0010,
    (0x1800, 1): 0x180 + 125,
    (0x1800, 2): 0xFE,
    (0x1800, 5): 0,
    (0x1801, 1): 0x280 + 125,
    (0x1801, 2): 1,
    (0x1A00, 0): 3,
    (0x1A00, 1): 0x60040020,
    (0x1A00, 2): 0x5F1D0010,
    (0x1A00, 3): 0x5F190010,
    (0x1A01, 1): 0x60040020,
    (0x1A01, 2): 0x5F1D0010,
    (0x1A01, 3): 0x5F190010,
    (0x2003, 0): 1,
    (0x2004, 0): 1,
    (0x2005, 2): 5,
    (0x5F09, 1): 0,
    (0x5F09, 2): 0,
    (0x5F0A, 1): 0x7D,
    (0x5F0A, 3): 0,
    (0x5F10, 0): 5,
    (0x5F12, 0): 0x0A,
    (0x5F1B, 1): 2,
    (0x5F1B, 2): 0,
    (0x6000, 0): 4,
    (0x6001, 0): 720,
    (0x6002, 0): 0x027FFFD8,
    (0x6200, 0): 0,
    (0x6501, 0): 720,
    (0x6502, 0): 932067,
    (0x6504, 0): 0x3001,
    (0x6506, 0): 0x0010,
    (0x6507, 0): 0x01000302,
    (0x6508, 0): 0xFFFFFFFF,
    (0x650A, 2): -335544320,
    (0x650A, 3): 335544320,
}

# Manual 5.5.1 table 31.
EMCY_CODES = [0x0000, 0x3200, 0x8120, 0x8140, 0xFF12, 0xFF20]

# Manual 5.3.2 table 27 / 5.3.3 table 28: bit -> the name(s) the profile gives it.
CONTROL_BITS = {
    0: "reserved_bit0",
    1: "reserved_bit1",
    2: "set_point1_valid",
    3: "display_range_extended",
    4: "acknowledge_target_window1_static",
    5: "reserved_bit5",
    6: "acknowledge_set_point2",
    7: "data_identifier_ascii",
    8: "guarding_bit",
    9: "set_point2_valid",
    10: "acknowledge_set_point1",
    11: "led1_green_left",
    12: "led3_green_right",
    13: "led4_red_right",
    14: "led2_red_left",
    15: "led_blinking",
}
CONTROL_RESERVED = {0, 1, 5}
STATUS_BITS = {
    0: {"direction_cw"},
    1: {"direction_ccw"},
    2: {"set_point1_valid"},
    3: {"target_window2_dynamic", "set_point2_acknowledged"},
    4: {"target_window1_static"},
    5: {"target_window1_dynamic", "set_point1_acknowledged"},
    6: {"deviation"},
    7: {"battery_empty"},
    8: {"guarding_bit"},
    9: {"incremental_measurement", "data_identifier_ascii"},
    10: {"set_point2_valid"},
    11: {"battery_critical"},
    12: {"sensor_error"},
    13: {"key_left_pressed"},
    14: {"key_star_pressed"},
    15: {"key_up_pressed"},
}


@pytest.fixture(scope="module")
def loaded():
    return load_profile("ap05")


@pytest.fixture(scope="module")
def od_125(loaded) -> canopen.ObjectDictionary:
    return import_eds(loaded.eds_path, FACTORY_NODE_ID)


def _var(od: canopen.ObjectDictionary, index: int, sub: int):
    entry = od[index]
    if isinstance(entry, canopen.objectdictionary.ODVariable):
        assert sub == 0
        return entry
    return entry[sub]


def _struct_format(pdo: Pdo, loaded) -> str:
    """Little-endian struct format of a PDO from its mapping and the profile signal types."""
    codes = {8: "B", 16: "H", 32: "I"}
    signed = {8: "b", 16: "h", 32: "i"}
    fmt = "<"
    for entry in pdo.mapping:
        sig: Signal | None = loaded.profile.signal_for(entry.object)
        if sig is not None and sig.type in ("string", "bytes"):
            fmt += f"{entry.bits // 8}s"
        elif sig is not None and sig.type.startswith("int"):
            fmt += signed[entry.bits]
        else:
            fmt += codes[entry.bits]
    return fmt


def test_eds_imports_without_any_warning(loaded):
    od = import_eds(loaded.eds_path)
    assert od.device_information.vendor_number == 0x195
    assert od.device_information.product_name == "AP05"
    assert od.device_information.nr_of_RXPDO == 2
    assert od.device_information.nr_of_TXPDO == 2
    assert od.device_information.LSS_supported is False
    assert od.device_information.allowed_baudrates == {
        125_000,
        250_000,
        500_000,
        800_000,
        1_000_000,
    }


@pytest.mark.parametrize(("index", "sub", "data_type", "access", "pdo"), MANUAL_OBJECTS)
def test_every_manual_object_exists_with_its_type_access_and_pdo_mapping(
    loaded, index, sub, data_type, access, pdo
):
    var = _var(loaded.od, index, sub)
    assert var.data_type == data_type, f"0x{index:04X}:{sub:02X} data type"
    assert var.access_type == access, f"0x{index:04X}:{sub:02X} access"
    assert var.pdo_mappable is pdo, f"0x{index:04X}:{sub:02X} PDO mapping"


def test_the_object_descriptions_cover_exactly_the_overview_table():
    assert len(TABLE_33) == 66  # 5.7.2.1 .. 5.7.2.66
    assert sorted({i for i, *_ in MANUAL_OBJECTS}) == sorted(TABLE_33)


def test_the_eds_has_no_object_the_manual_does_not_document(loaded):
    manual = set(TABLE_33) | {0x5F1D}  # 5F1Dh: the dummy mapped by 1A00h/1A01h
    assert set(loaded.od.keys()) == manual


def test_eds_object_lists_and_sub_numbers_are_consistent(loaded):
    eds = configparser.ConfigParser()
    eds.optionxform = str  # type: ignore[assignment,method-assign]
    eds.read(loaded.eds_path, encoding="ascii")
    lists: dict[str, list[int]] = {}
    for section in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        n = int(eds[section]["SupportedObjects"])
        lists[section] = [int(eds[section][str(i)], 0) for i in range(1, n + 1)]
    listed = [i for objs in lists.values() for i in objs]
    assert sorted(listed) == sorted(loaded.od.keys())
    assert lists["MandatoryObjects"] == [0x1000, 0x1001, 0x1018]
    assert lists["ManufacturerObjects"] == [i for i in listed if 0x2000 <= i <= 0x5FFF]
    for i in listed:
        sec = eds[f"{i:04X}"]
        subs = [s for s in eds.sections() if s.upper().startswith(f"{i:04X}SUB")]
        if int(sec.get("ObjectType", "0x7"), 0) == 0x7:
            assert not subs
        else:
            assert int(sec["ObjectType"], 0) in (0x8, 0x9)
            assert int(sec["SubNumber"]) == len(subs), f"0x{i:04X}"


@pytest.mark.parametrize(("index", "sub"), ABSENT_SUBS)
def test_sub_indices_the_manual_says_are_unused_are_absent(loaded, index, sub):
    with pytest.raises(KeyError):
        loaded.od[index][sub]


def test_records_sub0_gives_the_highest_sub_index(loaded):
    for index in loaded.od.keys():
        entry = loaded.od[index]
        if isinstance(entry, canopen.objectdictionary.ODVariable) or index == 0x1003:
            continue  # 1003h:00 counts the stored errors (manual 5.7.2.4)
        highest = max(s for s in entry.subindices if s != 0)
        # 1400h/1401h/1800h/1801h: sub 0 = 5 (highest), sub 4 is missing
        assert entry[0].default == highest, f"0x{index:04X}:00"


@pytest.mark.parametrize(("key", "value"), list(DEFAULTS_AT_NODE_125.items()))
def test_defaults_match_the_manual_at_the_factory_node_id(od_125, key, value):
    index, sub = key
    assert _var(od_125, index, sub).default == value


def test_node_id_relative_defaults_are_written_with_nodeid(loaded):
    for index, sub in [(0x1014, 0), (0x1200, 1), (0x1200, 2), (0x1400, 1), (0x1401, 1)]:
        assert _var(loaded.od, index, sub).relative, f"0x{index:04X}:{sub:02X}"
    for index in (0x1800, 0x1801):
        assert _var(loaded.od, index, 1).relative


def test_profile_loads_with_factory_settings(loaded):
    p = loaded.profile
    assert p.family == "ap05"
    assert p.device_type == 0x00050196
    assert p.factory.node_id == FACTORY_NODE_ID
    assert p.factory.bitrate_kbps == "auto"
    assert {
        "position_indicator",
        "guarding_bit",
        "external_heartbeat",
        "alphanumeric_display",
        "auto_id",
    } <= set(p.features)


def test_guarding_bit_feature_is_control_bit_8_echoed_in_status_bit_8(loaded):
    g = loaded.profile.features["guarding_bit"]
    assert ObjRef.parse(g["control"]) == ObjRef(0x5F0C, 0)
    assert ObjRef.parse(g["status"]) == ObjRef(0x5F19, 0)
    assert g["control_bit"] == 8 and g["status_bit"] == 8


def test_external_heartbeat_and_auto_id_features_name_their_objects(loaded):
    f = loaded.profile.features
    assert ObjRef.parse(f["external_heartbeat"]["interval"]) == ObjRef(0x5F09, 1)
    assert ObjRef.parse(f["external_heartbeat"]["source"]) == ObjRef(0x5F09, 2)
    assert f["external_heartbeat"]["sources"] == {0: "rpdo", 1: "sync"}
    assert ObjRef.parse(f["auto_id"]["object"]) == ObjRef(0x5F0A, 2)
    assert f["auto_id"]["reply_cob_id"] == 0x580 + FACTORY_NODE_ID


def test_alphanumeric_rows_cover_six_characters_in_rpdo_bytes_0_to_5(loaded):
    f = loaded.profile.features["alphanumeric_display"]
    assert ObjRef.parse(f["mode_object"]) == ObjRef(0x5F1B, 2) and f["mode_value"] == 3
    assert f["data_identifier_bit"] == 7 and f["text_length"] == 6
    rpdos = {r.number: r for r in loaded.profile.rpdos}
    for row in (1, 2):
        spec = f["rows"][row]
        mapping = [e.object for e in rpdos[spec["rpdo"]].mapping]
        assert mapping[:2] == [ObjRef.parse(spec["chars_1_4"]), ObjRef.parse(spec["chars_5_6"])]


def test_every_control_word_bit_is_named_and_writable_unless_reserved(loaded):
    cw = loaded.profile.signal("control_word")
    assert cw.object == ObjRef(0x5F0C, 0) and cw.access == "rw" and cw.type == "uint16"
    by_bit = {b.bit: b for b in cw.bits}
    assert {b: f.name for b, f in by_bit.items()} == CONTROL_BITS
    for bit, field in by_bit.items():
        assert field.width == 1
        assert field.writable is (bit not in CONTROL_RESERVED), field.name


def test_every_status_word_bit_is_named(loaded):
    sw = loaded.profile.signal("status_word")
    assert sw.object == ObjRef(0x5F19, 0) and sw.access == "ro" and sw.type == "uint16"
    named: dict[int, set[str]] = {}
    for b in sw.bits:
        named.setdefault(b.bit, set()).add(b.name)
        assert not b.writable
    assert named == STATUS_BITS


def test_tpdos_are_position_dummy_status_word_as_1a00h_and_1a01h_map_them(loaded):
    tpdos = {t.number: t for t in loaded.profile.tpdos}
    assert set(tpdos) == {1, 2}
    expected = [(ObjRef(0x6004, 0), 32), (ObjRef(0x5F1D, 0), 16), (ObjRef(0x5F19, 0), 16)]
    for n, t in tpdos.items():
        assert [(e.object, e.bits) for e in t.mapping] == expected
        assert t.length == 8
        assert t.cob_id == default_cob_id("tpdo", n) and t.add_node_id
    assert tpdos[1].transmission_type == 254 and tpdos[1].event_timer_ms == 0
    assert tpdos[2].transmission_type == 1
    # 1801h:05 and 180xh:03 are read-only compatibility entries: nothing to write
    assert tpdos[2].event_timer_ms is None
    assert tpdos[1].inhibit_time_100us is None and tpdos[2].inhibit_time_100us is None


def test_rpdos_are_set_point_chars_control_word_as_1600h_and_1601h_map_them(loaded):
    rpdos = {r.number: r for r in loaded.profile.rpdos}
    assert rpdos[1].cob_id == 0x200 and rpdos[2].cob_id == 0x300
    assert [(e.object, e.bits) for e in rpdos[1].mapping] == [
        (ObjRef(0x5F16, 3), 32),
        (ObjRef(0x5F16, 4), 16),
        (ObjRef(0x5F0C, 0), 16),
    ]
    assert [(e.object, e.bits) for e in rpdos[2].mapping] == [
        (ObjRef(0x5F16, 1), 32),
        (ObjRef(0x5F16, 2), 16),
        (ObjRef(0x5F0C, 0), 16),
    ]
    for r in rpdos.values():
        assert r.transmission_type == 255 and r.length == 8
        assert r.event_timer_ms is None and r.inhibit_time_100us is None


def test_profile_pdo_mappings_equal_the_eds_mapping_objects(loaded):
    for pdos, base in ((loaded.profile.tpdos, 0x1A00), (loaded.profile.rpdos, 0x1600)):
        for pdo in pdos:
            rec = loaded.od[base + pdo.number - 1]
            assert rec[0].default == len(pdo.mapping)
            for i, e in enumerate(pdo.mapping, start=1):
                assert rec[i].default == (e.object.index << 16) | (e.object.sub << 8) | e.bits


def test_tpdo2_of_the_communication_example_decodes_position_250_and_status_0401h(loaded):
    # manual 5.3.1.3: 281h DLC 8, position FAh, status word 0401h (dummy cells restored)
    tpdo2 = next(t for t in loaded.profile.tpdos if t.number == 2)
    assert tpdo2.cob_id + 1 == 0x281
    position, dummy, status = struct.unpack(
        _struct_format(tpdo2, loaded), bytes.fromhex("FA 00 00 00 00 00 01 04")
    )
    assert (position, dummy, status) == (250, 0, 0x0401)
    sw = loaded.profile.signal("status_word")
    set_bits = {b.name for b in sw.bits if status >> b.bit & 1}
    assert set_bits == {"direction_cw", "set_point2_valid"}


def test_rpdo2_of_the_communication_example_encodes_set_point_300_with_set_point2_valid(loaded):
    # manual 5.3.1.3: 301h DLC 8: 2C 01 00 00 00 00 00 02 = set point 300, control word 0200h
    rpdo2 = next(r for r in loaded.profile.rpdos if r.number == 2)
    assert rpdo2.cob_id + 1 == 0x301
    cw = loaded.profile.signal("control_word")
    control = sum(1 << b.bit for b in cw.bits if b.name == "set_point2_valid")
    data = struct.pack(_struct_format(rpdo2, loaded), 300, b"\x00\x00", control)
    assert data == bytes.fromhex("2C 01 00 00 00 00 00 02")


def test_position_and_set_points_decode_signed(loaded):
    for name in ("position", "set_point1", "set_point2"):
        assert loaded.profile.signal(name).type == "int32"
    assert loaded.profile.signal("position").object == ObjRef(0x6004, 0)


@pytest.mark.parametrize("code", EMCY_CODES)
def test_emcy_codes_of_table_31_have_texts(loaded, code):
    assert loaded.profile.emcy[code]


def test_configuration_signals_carry_the_manual_ranges(loaded):
    p = loaded.profile
    expected = {
        "calibration_value": (-19999, 99999),
        "application_offset": (-19999, 19999),
        "target_window1": (0, 9999),
        "target_window2": (0, 9999),
        "loop_length": (0, 9999),
        "decimal_places": (0, 4),
        "measuring_steps_per_revolution": (1, 65535),
        "configuration_start_delay": (1, 60),
        "operating_mode": (0, 3),
        "display_factor": (0, 8),
        "node_id": (1, 127),
    }
    for name, (lo, hi) in expected.items():
        s = p.signal(name)
        assert (s.min, s.max) == (lo, hi), name
        assert s.transport == "sdo" and s.access == "rw", name
        var = loaded.od_var(s.object)
        assert (var.min, var.max) == (lo, hi), name
    assert p.signal("operating_mode").values[3] == "alphanumeric_display"
    assert p.signal("external_heartbeat_interval").unit == "ms"


def test_boot_defaults_start_tpdo1_cycle_and_heartbeat_in_the_allowed_range(loaded):
    boot = loaded.profile.boot
    assert boot.supervision == "heartbeat"
    assert boot.heartbeat_ms == 0 or boot.heartbeat_ms >= 10  # 1017h: 0, 10..65535 ms
    writes = {w.object: w.value for w in boot.sdo}
    assert writes[ObjRef(0x1800, 5)] > 0
    for w in boot.sdo:
        var = loaded.od_var(w.object)
        assert var is not None and "w" in var.access_type, str(w.object)


def test_every_signal_object_has_a_matching_size_in_the_eds(loaded):
    sizes = {U8: 8, U16: 16, U32: 32, I16: 16, I32: 32}
    for s in loaded.profile.signals:
        var = loaded.od_var(s.object)
        assert var is not None
        if var.data_type in sizes:
            assert s.bit_length == sizes[var.data_type], s.name


def test_writable_signals_are_writable_by_sdo_or_mapped_in_an_rpdo(loaded):
    rpdo_objects = {e.object for r in loaded.profile.rpdos for e in r.mapping}
    for s in loaded.profile.signals:
        if s.access == "ro":
            continue
        if s.transport == "pdo":
            assert s.object in rpdo_objects, s.name
        else:
            assert "w" in loaded.od_var(s.object).access_type, s.name
