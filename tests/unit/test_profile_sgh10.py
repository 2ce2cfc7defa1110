"""The SGH10 / SGH10L profile and EDS match the SIKO SGH10 user manual.

Facts from the manual (chapter 4.7 object tables, 4.3.1.1 Table 5, 4.5.1 Table 9) are copied here
as data; the test never reads the manual. Imports: canopen_gateway.profiles, canopen data types only.
"""

from __future__ import annotations

import struct

import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles import PROFILE_DIR, LoadedProfile, import_eds, load_profile
from canopen_gateway.profiles.schema import KNOWN_FEATURES

U8, U16, U32 = datatypes.UNSIGNED8, datatypes.UNSIGNED16, datatypes.UNSIGNED32
I16, I32, VS = datatypes.INTEGER16, datatypes.INTEGER32, datatypes.VISIBLE_STRING

# SGH10 manual 4.7.1 Table 11 + 4.7.2 object description: (index, sub, data type, access).
# Sub-index 04h of 1800h/1801h is "not used, access attempt generates error message".
MANUAL_OBJECTS: list[tuple[int, int, int, str]] = [
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
    (0x1010, 0, U8, "const"),
    *[(0x1010, s, U32, "rw") for s in range(1, 5)],
    (0x1011, 0, U8, "const"),
    *[(0x1011, s, U32, "rw") for s in range(1, 5)],
    (0x1014, 0, U32, "rw"),
    (0x1017, 0, U16, "rw"),
    (0x1018, 0, U8, "const"),
    *[(0x1018, s, U32, "ro") for s in range(1, 5)],
    (0x1200, 0, U8, "const"),
    (0x1200, 1, U32, "ro"),
    (0x1200, 2, U32, "ro"),
    (0x1800, 0, U8, "const"),
    (0x1800, 1, U32, "rw"),
    (0x1800, 2, U8, "rw"),
    (0x1800, 3, U16, "ro"),
    (0x1800, 5, U16, "rw"),
    (0x1801, 0, U8, "const"),
    (0x1801, 1, U32, "rw"),
    (0x1801, 2, U8, "rw"),
    (0x1801, 3, U16, "ro"),
    (0x1801, 5, U16, "ro"),
    (0x1A00, 0, U8, "const"),
    (0x1A00, 1, U32, "ro"),
    (0x1A00, 2, U32, "ro"),
    (0x1A01, 0, U8, "const"),
    (0x1A01, 1, U32, "ro"),
    (0x1A01, 2, U32, "ro"),
    (0x5000, 0, U32, "ro"),
    (0x5F0A, 0, U8, "const"),
    (0x5F0A, 1, U8, "rw"),
    (0x5F0A, 2, U8, "rw"),
    (0x6000, 0, U16, "rw"),
    (0x6002, 0, U32, "rw"),
    (0x6003, 0, U32, "rw"),  # "not used"; CiA 406 type
    (0x6004, 0, U32, "ro"),  # "not used"; CiA 406 type
    (0x6005, 0, U8, "ro"),
    (0x6005, 1, U32, "rw"),
    (0x6005, 2, U32, "rw"),
    (0x6010, 0, U8, "ro"),
    (0x6010, 1, I32, "rw"),
    (0x6020, 0, U8, "ro"),
    (0x6020, 1, I32, "ro"),
    (0x6030, 0, U8, "ro"),
    (0x6030, 1, I16, "ro"),
    (0x6200, 0, U16, "rw"),
    (0x6400, 0, U8, "ro"),
    (0x6400, 1, U8, "ro"),
    (0x6400, 2, U8, "ro"),
    (0x6401, 0, U8, "ro"),
    (0x6401, 1, I32, "rw"),
    (0x6401, 2, I32, "rw"),
    (0x6402, 0, U8, "ro"),
    (0x6402, 1, I32, "rw"),
    (0x6402, 2, I32, "rw"),
    (0x6500, 0, U16, "ro"),
    (0x6501, 0, U32, "ro"),
    (0x6502, 0, U16, "ro"),
    (0x6503, 0, U16, "ro"),
    (0x6504, 0, U16, "ro"),
    (0x6505, 0, U16, "ro"),
    (0x6506, 0, U16, "ro"),
    (0x6507, 0, U32, "ro"),
    (0x6508, 0, U32, "ro"),
    (0x6509, 0, I32, "ro"),
    (0x650A, 0, U8, "ro"),
    (0x650A, 1, I32, "ro"),
    (0x650A, 2, I32, "ro"),
    (0x650A, 3, I32, "ro"),
    (0x650B, 0, U32, "ro"),
    (0x650C, 0, U8, "ro"),
    (0x650C, 1, I32, "ro"),
]

# Defaults from the object description (4.7.2.x); node-relative ones as written in the EDS.
MANUAL_DEFAULTS: dict[tuple[int, int], int | str] = {
    (0x1000, 0): 0x000A0196,  # 4.7.2.1
    (0x1005, 0): 0x80,  # 4.7.2.5
    (0x1008, 0): "SGH10",  # 4.7.2.6
    (0x1009, 0): "V100",  # 4.7.2.7
    (0x100A, 0): "V100",  # 4.7.2.8
    (0x100C, 0): 0,
    (0x100D, 0): 0,
    (0x1010, 0): 4,
    (0x1011, 0): 4,
    (0x1017, 0): 0,  # 4.7.2.14: heartbeat off
    (0x1018, 1): 0x195,  # 4.7.2.15 / 4.6: SIKO
    (0x1018, 2): 0xFFFFFFFF,
    (0x1018, 3): 0xFFFFFFFF,
    (0x1800, 0): 5,
    (0x1800, 2): 0xFE,  # 4.7.2.17
    (0x1800, 3): 0,
    (0x1800, 5): 0,  # event timer off
    (0x1801, 2): 1,  # 4.7.2.18: every SYNC
    (0x1801, 5): 0,
    (0x1A00, 0): 2,
    (0x1A00, 1): 0x60200120,  # 4.7.2.19
    (0x1A00, 2): 0x60300110,
    (0x1A01, 0): 2,
    (0x1A01, 1): 0x60200120,  # 4.7.2.20
    (0x1A01, 2): 0x60300110,
    (0x5F0A, 1): 1,  # 4.7.2.22: node 1
    (0x5F0A, 2): 5,  # 500 kbit/s
    (0x6000, 0): 0x0004,  # 4.7.2.23
    (0x6002, 0): 10239,  # 4.7.2.24
    (0x6005, 1): 100000,  # 4.7.2.27 (decimal kept, see notes)
    (0x6005, 2): 100,
    (0x6010, 1): 0,
    (0x6200, 0): 0,  # 4.7.2.31
    (0x6401, 1): 0,
    (0x6402, 2): 0,
    (0x6500, 0): 0x0004,
    (0x6501, 0): 100000,
    (0x6502, 0): 1,
    (0x6504, 0): 0x3001,  # 4.7.2.39
    (0x6506, 0): 0x0000,
    (0x6507, 0): 0x01000302,  # 4.7.2.42
    (0x6508, 0): 0xFFFFFFFF,  # 4.7.2.43: not supported
    (0x650A, 0): 3,
    (0x650A, 2): -20478,  # 4.7.2.45: FFFFB002h
    (0x650A, 3): 30717,  # 000077FDh
}

NODE_RELATIVE_DEFAULTS = {
    (0x1014, 0): 0x80,  # 4.7.2.13: 80h + Node-ID
    (0x1200, 1): 0x600,  # 4.7.2.16
    (0x1200, 2): 0x580,
    (0x1800, 1): 0x180,  # 4.7.2.17
    (0x1801, 1): 0x280,  # 4.7.2.18
}

# 4.5.1 Table 9
MANUAL_EMCY = {0x0000, 0x8120, 0x8140, 0xFF05, 0xFF15, 0xFF16}

EDS_PATH = PROFILE_DIR / "sgh10.eds"


@pytest.fixture(scope="module")
def lp() -> LoadedProfile:
    return load_profile("sgh10")


def _var(lp: LoadedProfile, index: int, sub: int) -> ODVariable:
    var = lp.od_var(ObjRef(index, sub))
    assert var is not None, f"0x{index:04X}:{sub:02X} missing from sgh10.eds"
    return var


def test_eds_imports_without_any_warning() -> None:
    od = import_eds(EDS_PATH)
    assert 0x6020 in od


def test_eds_device_info_matches_manual() -> None:
    info = import_eds(EDS_PATH).device_information
    assert info.vendor_number == 0x195
    assert info.product_number == 0xFFFFFFFF
    assert info.nr_of_TXPDO == 2
    assert info.nr_of_RXPDO == 0
    assert info.LSS_supported is True
    # 4.7.2.22 / 4.6.2.2: 20, 50, 125, 250, 500, 800, 1000 kbit/s; no 10 kbit/s
    assert info.allowed_baudrates == {k * 1000 for k in (20, 50, 125, 250, 500, 800, 1000)}


@pytest.mark.parametrize(("index", "sub", "data_type", "access"), MANUAL_OBJECTS)
def test_every_manual_object_is_in_eds_with_type_and_access(
    lp: LoadedProfile, index: int, sub: int, data_type: int, access: str
) -> None:
    var = _var(lp, index, sub)
    assert var.data_type == data_type
    assert var.access_type == access


def test_eds_has_no_object_the_manual_does_not_document(lp: LoadedProfile) -> None:
    documented = {(i, s) for i, s, _, _ in MANUAL_OBJECTS}
    in_eds = set()
    for entry in lp.od.values():
        if isinstance(entry, (ODRecord, ODArray)):
            in_eds |= {(entry.index, v.subindex) for v in entry.values()}
        else:
            in_eds.add((entry.index, 0))
    assert in_eds == documented


def test_unused_tpdo_subindex_4_is_absent(lp: LoadedProfile) -> None:
    assert lp.od_var(ObjRef(0x1800, 4)) is None
    assert lp.od_var(ObjRef(0x1801, 4)) is None


def test_records_and_arrays_sub0_counts_highest_subindex(lp: LoadedProfile) -> None:
    for entry in lp.od.values():
        if isinstance(entry, (ODRecord, ODArray)) and entry.index != 0x1003:
            highest = max(v.subindex for v in entry.values())
            assert entry[0].default == highest, f"0x{entry.index:04X}:00"


@pytest.mark.parametrize(("key", "value"), sorted(MANUAL_DEFAULTS.items()))
def test_defaults_match_manual(lp: LoadedProfile, key: tuple[int, int], value: int | str) -> None:
    assert _var(lp, *key).default == value


@pytest.mark.parametrize(("key", "base"), sorted(NODE_RELATIVE_DEFAULTS.items()))
def test_node_relative_defaults_are_nodeid_expressions(
    lp: LoadedProfile, key: tuple[int, int], base: int
) -> None:
    var = _var(lp, *key)
    assert var.relative
    assert var.default_raw.replace(" ", "").upper() == f"$NODEID+0X{base:X}"
    entry = import_eds(EDS_PATH, node_id=5)[key[0]]
    var5 = entry if isinstance(entry, ODVariable) else entry[key[1]]
    assert var5.default == base + 5


def test_mapped_objects_are_pdo_mappable(lp: LoadedProfile) -> None:
    assert _var(lp, 0x6020, 1).pdo_mappable
    assert _var(lp, 0x6030, 1).pdo_mappable
    assert _var(lp, 0x6010, 1).pdo_mappable  # 4.7.2.28 "PDO mapping yes"
    assert not _var(lp, 0x6200, 0).pdo_mappable


def test_value_ranges_in_eds_match_manual(lp: LoadedProfile) -> None:
    assert (_var(lp, 0x6010, 1).min, _var(lp, 0x6010, 1).max) == (-10239, 10239)
    for index in (0x6401, 0x6402):
        for sub in (1, 2):
            assert (_var(lp, index, sub).min, _var(lp, index, sub).max) == (-20478, 40956)
    assert (_var(lp, 0x5F0A, 1).min, _var(lp, 0x5F0A, 1).max) == (1, 127)
    assert (_var(lp, 0x5F0A, 2).min, _var(lp, 0x5F0A, 2).max) == (1, 7)


def test_profile_loads_with_factory_settings(lp: LoadedProfile) -> None:
    p = lp.profile
    assert p.family == "sgh10"
    assert p.device_type == 0x000A0196
    assert p.factory.node_id == 1
    assert p.factory.bitrate_kbps == 500
    assert set(p.features) <= KNOWN_FEATURES
    assert {"lss_slave", "work_areas", "node_id_object"} <= set(p.features)


def test_lss_feature_carries_identity_and_cob_ids(lp: LoadedProfile) -> None:
    lss = lp.profile.features["lss_slave"]
    assert lss["cob_id_master_to_slave"] == 0x7E5  # 4.6
    assert lss["cob_id_slave_to_master"] == 0x7E4
    assert lss["vendor_id"] == 0x195
    assert lss["product_code"] == 0xFFFFFFFF
    assert lss["revision_number"] == 0xFFFFFFFF
    assert lss["bit_timing_indices"] == [0, 1, 2, 3, 4, 6, 7]  # 4.6.2.2


def test_default_tpdos_match_table5_and_mapping_objects(lp: LoadedProfile) -> None:
    tpdos, rpdos = lp.profile.layout()
    assert rpdos == []
    by_number = {t.number: t for t in tpdos}
    assert set(by_number) == {1, 2}
    for number, cob, ttype in ((1, 0x180, 254), (2, 0x280, 1)):
        pdo = by_number[number]
        assert pdo.cob_id == cob and pdo.add_node_id
        assert pdo.transmission_type == ttype
        assert pdo.length == 6  # bytes 0-3 position, 4-5 velocity
        assert [(str(e.object), e.bits) for e in pdo.mapping] == [
            ("0x6020:01", 32),
            ("0x6030:01", 16),
        ]
        # the profile's mapping equals the EDS mapping object defaults (1A00h / 1A01h)
        mapping_index = 0x1A00 + number - 1
        eds_entries = [_var(lp, mapping_index, s).default for s in (1, 2)]
        assert eds_entries == [
            (e.object.index << 16) | (e.object.sub << 8) | e.bits for e in pdo.mapping
        ]
    assert by_number[1].event_timer_ms == 0  # factory: timer off (6200h = 0)


def test_tpdo_frame_decodes_position_and_velocity_at_table5_positions(lp: LoadedProfile) -> None:
    # Table 5: bytes 0-3 position (LSB first), bytes 4-5 velocity (LSB first)
    frame = bytes([0xFE, 0x01, 0x00, 0x00, 0x9C, 0xFF])  # 510 steps, -100 mm/s
    position, velocity = struct.unpack("<ih", frame)
    p = lp.profile
    assert position * p.signal("position").scale == pytest.approx(51.0)
    assert velocity * p.signal("velocity").scale == -100
    assert p.signal("position").type == "int32"
    assert p.signal("velocity").type == "int16"


def test_emcy_codes_of_table9_are_present(lp: LoadedProfile) -> None:
    assert set(lp.profile.emcy) == MANUAL_EMCY
    assert "work area 1" in lp.profile.emcy[0xFF15]
    assert "work area 2" in lp.profile.emcy[0xFF16]


def test_status_words_name_every_documented_bit(lp: LoadedProfile) -> None:
    p = lp.profile
    assert {b.bit: b.name for b in p.signal("alarms").bits} == {
        0: "position_value_invalid",
        12: "work_area_1_limit_exceeded",
        13: "work_area_2_limit_exceeded",
    }
    for name in ("work_area_1_state", "work_area_2_state"):
        assert {b.bit: b.name for b in p.signal(name).bits} == {
            0: "out_of_range",
            1: "above_high_limit",
            2: "below_low_limit",
        }
    assert {b.bit for b in p.signal("error_register").bits} == {0, 4, 7}
    direction = next(b for b in p.signal("operating_parameters").bits if b.bit == 3)
    assert direction.writable


def test_signal_types_agree_with_eds(lp: LoadedProfile) -> None:
    sizes = {U8: "uint8", U16: "uint16", U32: "uint32", I16: "int16", I32: "int32", VS: "string"}
    for s in lp.profile.signals:
        var = lp.od_var(s.object)
        assert var is not None
        assert sizes[var.data_type] == s.type, s.name
        if s.access == "rw":
            assert var.access_type == "rw", s.name


def test_boot_defaults_enable_heartbeat_and_timed_tpdo1(lp: LoadedProfile) -> None:
    boot = lp.profile.boot
    assert boot.supervision == "heartbeat"
    assert boot.heartbeat_ms >= 10  # 4.7.2.14: 0 or 10..65535 ms
    writes = {str(w.object): w.value for w in boot.sdo}
    assert writes["0x1800:05"] > 0
    assert writes["0x1800:02"] == 0xFE


def test_factory_node_id_and_bitrate_agree_with_eds(lp: LoadedProfile) -> None:
    codes = lp.profile.features["node_id_object"]["bitrate_codes_kbps"]
    assert _var(lp, 0x5F0A, 1).default == lp.profile.factory.node_id
    assert codes[_var(lp, 0x5F0A, 2).default] == lp.profile.factory.bitrate_kbps


def test_store_and_restore_signatures_are_save_and_load() -> None:
    # 4.7.2.11 / 4.7.2.12: bytes 73h 61h 76h 65h ("save"), 6Ch 6Fh 61h 64h ("load")
    p = load_profile("sgh10").profile
    assert p.features["node_id_object"]["store_signature"] == int.from_bytes(b"save", "little")


def test_sdo_read_example_calibration_value_matches_eds_type(lp: LoadedProfile) -> None:
    # 4.4.1.4: 601h 40 10 60 01 -> 581h 43 10 60 01 FE 01 00 00 (6010h:01 = 510d)
    response = bytes.fromhex("43106001FE010000")
    index, sub = struct.unpack_from("<HB", response, 1)
    var = _var(lp, index, sub)
    valid_bytes = 4 - ((response[0] >> 2) & 0x3)  # DS-301 expedited, bits 3-2
    assert valid_bytes == len(var) // 8 == 4
    assert var.decode_raw(response[4:8]) == 510


def test_sdo_write_example_cycle_timer_matches_eds_type(lp: LoadedProfile) -> None:
    # 4.4.1.4: 601h 2B 00 62 00 94 11 00 00 -> 581h 60 00 62 00 (6200h = 4500d)
    request = bytes.fromhex("2B00620094110000")
    index, sub = struct.unpack_from("<HB", request, 1)
    var = _var(lp, index, sub)
    valid_bytes = 4 - ((request[0] >> 2) & 0x3)
    assert valid_bytes == len(var) // 8 == 2
    assert var.access_type == "rw"
    assert var.decode_raw(request[4:6]) == 4500
