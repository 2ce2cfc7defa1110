"""Specification tests for the BEI IDEACOD POSI+ profiles (posi_plus, posi_sf).

The object tables below are copied from manual 002 (ch. 4, 5, 6 and the appendix) so the tests run
without the manual. Imports only the profile loader and canopen's data type constants.
"""

from __future__ import annotations

import pytest
from canopen.objectdictionary import datatypes as dt

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles import PROFILE_DIR, import_eds, load_profile

U8, U16, U32, I16, I32, STR = (
    dt.UNSIGNED8,
    dt.UNSIGNED16,
    dt.UNSIGNED32,
    dt.INTEGER16,
    dt.INTEGER32,
    dt.VISIBLE_STRING,
)

# manual 002 ch. 4 (1000h-1FFFh) and ch. 6 (6000h-9FFFh) object overviews, shared by both
# variants: (index, sub, data type, access, default or None)
COMMON_OBJECTS: list[tuple[int, int, int, str, int | str | None]] = [
    (0x1000, 0, U32, "ro", 0x00020196),
    (0x1001, 0, U8, "ro", 0x00),
    (0x1003, 0, U8, "rw", 0x00),
    (0x1003, 1, U32, "ro", None),
    (0x1005, 0, U32, "rw", 0x00000080),
    (0x100C, 0, U16, "rw", 0x0000),
    (0x100D, 0, U8, "rw", 0x00),
    (0x1010, 0, U8, "ro", 0x01),
    (0x1010, 1, U32, "rw", 0x00000001),
    (0x1011, 0, U8, "ro", 0x01),
    (0x1011, 1, U32, "rw", 0x00000001),
    (0x1014, 0, U32, "ro", "$NODEID+0x80"),
    (0x1016, 0, U8, "ro", 0x01),
    (0x1016, 1, U32, "rw", 0x00000000),
    (0x1017, 0, U16, "rw", 0x0000),
    (0x1018, 0, U8, "ro", 0x04),
    (0x1018, 1, U32, "ro", 0x00000184),
    (0x1018, 2, U32, "ro", 0x354D4850),
    (0x1018, 3, U32, "ro", 0x00010000),
    (0x1018, 4, U32, "ro", None),
    (0x1200, 0, U8, "ro", 0x02),
    (0x1200, 1, U32, "ro", "$NODEID+0x600"),
    (0x1200, 2, U32, "ro", "$NODEID+0x580"),
    (0x1800, 0, U8, "ro", 0x05),
    (0x1800, 1, U32, "rw", "$NODEID+0x180"),
    (0x1800, 2, U8, "rw", 0xFE),
    (0x1800, 3, U16, "rw", 0x0000),
    (0x1800, 5, U16, "rw", 0x0000),
    (0x1801, 0, U8, "ro", 0x05),
    (0x1801, 1, U32, "rw", "$NODEID+0x280"),
    (0x1801, 2, U8, "rw", 0x01),
    (0x1801, 3, U16, "rw", 0x0000),
    (0x1801, 5, U16, "rw", 0x0000),
    (0x1A00, 0, U8, "ro", 0x01),
    (0x1A00, 1, U32, "ro", 0x60040020),
    (0x1A01, 0, U8, "ro", 0x01),
    (0x1A01, 1, U32, "ro", 0x60040020),
    (0x6000, 0, U16, "rw", 0x0004),
    (0x6001, 0, U32, "rw", 0x00002000),
    (0x6002, 0, U32, "rw", 0x20000000),
    (0x6003, 0, U32, "rw", 0x00000000),
    (0x6004, 0, U32, "ro", None),
    (0x6200, 0, U16, "rw", 0x0000),
    (0x6500, 0, U16, "ro", 0x0004),
    (0x6501, 0, U32, "ro", 0x00002000),
    (0x6502, 0, U16, "ro", 0xFFFF),
    (0x6503, 0, U16, "ro", 0x0000),
    (0x6504, 0, U16, "ro", 0x0000),
    (0x6505, 0, U16, "ro", 0x0000),
    (0x6506, 0, U16, "ro", 0x0000),
    (0x6507, 0, U32, "ro", 0x01020301),
    (0x6508, 0, U32, "ro", 0xFFFFFFFF),
    (0x6509, 0, I32, "ro", None),
    (0x650A, 0, U8, "ro", 0x03),
    (0x650B, 0, U32, "ro", None),
]

# manual 002 ch. 5 (2000h-5FFFh) and ch. 6 cam objects: standard POSI+ only
POSI_PLUS_OBJECTS = COMMON_OBJECTS + [
    (0x1008, 0, STR, "const", "POSI+"),
    (0x6004, 0, U32, "ro", 0x00000ECB),
    (0x2002, 0, I16, "ro", None),
    (0x2005, 0, U8, "rw", 0x00),
    (0x2100, 0, U8, "rw", 0x01),
    (0x2101, 0, U8, "rw", 0x01),
    (0x6300, 0, U8, "ro", 0x01),
    (0x6300, 1, U8, "ro", 0x00),
    (0x6301, 0, U8, "ro", 0x01),
    (0x6301, 1, U8, "rw", 0x00),
    (0x6302, 0, U8, "ro", 0x01),
    (0x6302, 1, U8, "rw", 0x00),
    (0x6310, 0, U8, "ro", 0x01),
    (0x6310, 1, U32, "rw", 0x00000000),
    (0x6320, 0, U8, "ro", 0x01),
    (0x6320, 1, U32, "rw", 0x00000000),
    (0x650A, 1, U32, "ro", 0x00000000),
    (0x650A, 2, U32, "ro", 0x00000000),
    (0x650A, 3, U32, "ro", 0x1FFFFFFF),
]

# manual 002 appendix: objects of the POSI+ SF compatibility software
POSI_SF_OBJECTS = COMMON_OBJECTS + [
    (0x1008, 0, STR, "const", "POSI+ SF"),
    (0x6004, 0, U32, "ro", 0x1FFFFDE6),
    (0x1004, 0, U32, "ro", 0x00000002),
    (0x1004, 1, U32, "ro", 0x00000001),
    (0x1004, 2, U32, "ro", 0x00000001),
    (0x100F, 0, U32, "ro", 0x00000001),
    (0x6005, 0, U32, "rw", 0x00000000),
    (0x6006, 0, U32, "rw", 0x00000000),
    (0x6100, 0, U16, "rw", 0x0002),
    (0x6101, 0, U16, "rw", 0x0001),
    (0x650A, 1, I32, "ro", 0x00000000),
    (0x650A, 2, I32, "ro", 0x00000000),
    (0x650A, 3, I32, "ro", 0x1FFFFFFF),
    (0x650B, 0, U32, "ro", 0x12345678),
    (0x2000, 0, U32, "ro", 0x1FFFFDE6),
    (0x2100, 0, U16, "rw", 0x0000),
    (0x2101, 0, U16, "rw", 0x2000),
    (0x2102, 0, U32, "rw", 0x20000000),
    (0x2103, 0, U32, "rw", 0x00000000),
    (0x2104, 0, U32, "rw", 0x00000000),
    (0x2105, 0, U32, "rw", 0x00000000),
    (0x2200, 0, U16, "rw", 0x0000),
    (0x2300, 0, U32, "wo", None),
    (0x3000, 0, U8, "rw", 0x01),
    (0x3001, 0, U8, "rw", 0x00),
]

NOT_IN_SF = [0x2002, 0x2005, 0x6300, 0x6301, 0x6302, 0x6310, 0x6320]

CASES = {"posi_plus": POSI_PLUS_OBJECTS, "posi_sf": POSI_SF_OBJECTS}


def _od_var(lp, index: int, sub: int):
    var = lp.od_var(ObjRef(index, sub))
    assert var is not None, f"0x{index:04X}:{sub:02X} missing from {lp.eds_path.name}"
    return var


@pytest.mark.parametrize("family", ["posi_plus", "posi_sf"])
def test_eds_imports_without_any_warning(family: str) -> None:
    od = import_eds(PROFILE_DIR / f"{family}.eds")
    assert od[0x1018][1].default == 0x184


@pytest.mark.parametrize("family", ["posi_plus", "posi_sf"])
def test_every_manual_object_has_the_manual_type_access_and_default(family: str) -> None:
    lp = load_profile(family)
    for index, sub, data_type, access, default in CASES[family]:
        var = _od_var(lp, index, sub)
        where = f"{family} 0x{index:04X}:{sub:02X}"
        assert var.data_type == data_type, where
        assert var.access_type == access, where
        if isinstance(default, str) and default.startswith("$NODEID"):
            assert var.default_raw.replace(" ", "").upper() == default.upper(), where
        elif default is not None:
            assert var.default == default, where


def test_eds_marks_process_values_pdo_mappable() -> None:
    lp = load_profile("posi_plus")
    for ref in ["0x6004:00", "0x2002:00", "0x6300:01", "0x6503:00"]:
        assert lp.od_var(ObjRef.parse(ref)).pdo_mappable, ref
    assert not lp.od_var(ObjRef.parse("0x6003:00")).pdo_mappable


def test_eds_device_info_matches_identity_object() -> None:
    od = import_eds(PROFILE_DIR / "posi_plus.eds")
    info = od.device_information
    assert info.vendor_number == 0x184
    assert info.product_number == 0x354D4850
    assert info.nr_of_TXPDO == 2
    assert info.nr_of_RXPDO == 0
    assert 20_000 in info.allowed_baudrates
    assert 1_000_000 not in info.allowed_baudrates  # 2100h codes stop at 7 = 800 kbit/s


def test_compatibility_variant_has_none_of_the_standard_only_objects() -> None:
    od = import_eds(PROFILE_DIR / "posi_sf.eds")
    for index in NOT_IN_SF:
        assert index not in od, f"0x{index:04X} is POSI+ only"
    # same index, other meaning: 2100h/2101h are U16 scaling mirrors on POSI+ SF
    assert od[0x2100].name == "Operating Parameter"
    assert od[0x2101].name == "Resolution per Revolution"


@pytest.mark.parametrize("family", ["posi_plus", "posi_sf"])
def test_profile_loads_with_factory_node_1_at_20_kbit(family: str) -> None:
    p = load_profile(family).profile
    assert p.family == family
    assert p.factory.node_id == 1
    assert p.factory.bitrate_kbps == 20
    assert p.device_type == 0x00020196


@pytest.mark.parametrize("family", ["posi_plus", "posi_sf"])
def test_default_tpdos_follow_1800h_1801h_1a00h_1a01h(family: str) -> None:
    p = load_profile(family).profile
    tpdos, rpdos = p.layout()
    assert rpdos == []
    t1, t2 = tpdos
    assert (t1.number, t1.cob_id, t1.transmission_type, t1.event_timer_ms) == (1, 0x180, 254, 0)
    assert (t2.number, t2.cob_id, t2.transmission_type) == (2, 0x280, 1)
    for t in (t1, t2):
        assert [(str(e.object), e.bits) for e in t.mapping] == [("0x6004:00", 32)]
        assert t.length == 4


def _layout_bytes(pdo) -> list[tuple[str, int, int]]:
    """(object, first byte, length in bytes) in frame order."""
    out, pos = [], 0
    for e in pdo.mapping:
        out.append((str(e.object), pos, e.bits // 8))
        pos += e.bits // 8
    return out


TYPE2 = [("0x6004:00", 0, 4), ("0x2002:00", 4, 2), ("0x0006:00", 6, 2)]
DEFAULT = [("0x6004:00", 0, 4)]


@pytest.mark.parametrize(
    ("value", "pdo1", "pdo2"),
    [
        (0x00, DEFAULT, DEFAULT),
        (0x02, TYPE2, DEFAULT),
        (0x20, DEFAULT, TYPE2),
        (0x22, TYPE2, TYPE2),
    ],
)
def test_pdo_type_2005h_type_2_puts_speed_in_bytes_4_5_and_zeros_in_6_7(value, pdo1, pdo2) -> None:
    p = load_profile("posi_plus").profile
    assert p.pdo_variants is not None
    assert str(p.pdo_variants.selector) == "0x2005:00"
    assert p.pdo_variants.default == 0x00
    tpdos, _ = p.layout(value)
    t1, t2 = tpdos
    assert (t1.cob_id, t2.cob_id) == (0x180, 0x280)
    assert _layout_bytes(t1) == pdo1
    assert _layout_bytes(t2) == pdo2


def test_posi_plus_features_name_the_manual_objects() -> None:
    f = load_profile("posi_plus").profile.features
    assert set(f) == {"pdo_type_selector", "cams", "heartbeat_consumer", "node_id_object"}
    assert f["pdo_type_selector"]["selector"] == "0x2005:00"
    assert f["cams"]["state"] == "0x6300:01"
    assert f["cams"]["low_limit"] == "0x6310:01"
    assert f["cams"]["high_limit"] == "0x6320:01"
    assert f["heartbeat_consumer"]["emcy_code"] == 0x8130
    nid = f["node_id_object"]
    assert (nid["node_id"], nid["bitrate"]) == ("0x2101:00", "0x2100:00")
    assert nid["bitrate_kbps"][1] == 20
    # "save" / "load" in ASCII, little-endian on the wire (the manual prints them reversed)
    assert nid["store_signature"].to_bytes(4, "little") == b"save"
    assert nid["restore_signature"].to_bytes(4, "little") == b"load"


def test_posi_sf_features_use_the_appendix_objects() -> None:
    f = load_profile("posi_sf").profile.features
    assert set(f) == {"heartbeat_consumer", "node_id_object"}
    assert f["node_id_object"]["node_id"] == "0x6101:00"
    assert f["node_id_object"]["bitrate"] == "0x6100:00"


@pytest.mark.parametrize("family", ["posi_plus", "posi_sf"])
def test_emcy_codes_of_1003h_are_listed(family: str) -> None:
    emcy = load_profile(family).profile.emcy
    assert emcy[0x1000] == "Generic error"
    assert emcy[0x8130] == "Life guard error or heartbeat error"


def test_status_words_name_every_bit_of_the_manual_tables() -> None:
    p = load_profile("posi_plus").profile
    bits = {b.bit: b.name for b in p.signal("operating_status").bits}
    assert bits[0] == "code_sequence_ccw" and bits[2] == "scaling_function_enabled"
    assert {b.bit for b in p.signal("alarms").bits} == {0, 1, 12, 13, 14, 15}
    assert {b.bit for b in p.signal("warnings").bits} == {0, 1, 2, 3, 4, 5, 12, 13, 14, 15}
    assert p.signal("cam_state").bits[0].name == "cam1_active"
    err = {b.bit: b.name for b in p.signal("error_register").bits}
    assert err == {0: "generic_error", 4: "communication_error"}


def test_configuration_ranges_follow_the_object_descriptions() -> None:
    p = load_profile("posi_plus").profile
    assert (p.signal("node_number").min, p.signal("node_number").max) == (1, 127)
    assert p.signal("bitrate_code").values[1] == "20 kbit/s"
    assert p.signal("bitrate_code").max == 7
    assert p.signal("total_measuring_range").max == 0x20000000
    assert p.signal("preset_value").max == 0x1FFFFFFF
    assert p.signal("measuring_units_per_revolution").max == 8192


@pytest.mark.parametrize("family", ["posi_plus", "posi_sf"])
def test_boot_enables_heartbeat_and_a_cyclic_tpdo1(family: str) -> None:
    boot = load_profile(family).profile.boot
    assert boot.supervision == "heartbeat"
    assert boot.heartbeat_ms == 100
    writes = {str(w.object): w.value for w in boot.sdo}
    assert writes == {"0x1800:05": 100}


def test_sim_hints_name_position_and_speed_objects() -> None:
    sim = load_profile("posi_plus").profile.sim
    assert sim["position_object"] == "0x6004:00"
    assert sim["velocity_object"] == "0x2002:00"
    assert sim["physical_counts_per_revolution"] == 8192
