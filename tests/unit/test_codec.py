"""PDO codecs: the manuals' frames decoded and encoded byte for byte, and the decoder following
the PDO mapping the boot configuration leaves in the device."""

from __future__ import annotations

import pytest

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.pdo.codec import PdoMappingError, apply_pdo_writes, compile_node, pdo_objects
from canopen_gateway.profiles import load_profile

# AP05 manual 5.3.1.3, examples of communication (node 01h):
AP05_TPDO2_NODE1 = bytes.fromhex("FA00000000000104")  # 281: position 250, status word 0401h
AP05_RPDO2_NODE1 = bytes.fromhex("2C01000000000002")  # 301: set point 300, control word 0200h

# MSK5000 manual 4.3.1.2, the TPDO1 remapping example for node 1 (SDO data bytes 4-7, LE):
MSK_REMAP_NODE1 = [
    ("0x1800:01", 0x80000181),  # step 2: PDO off
    ("0x1A00:00", 0),  # step 3: mapping off
    ("0x1A00:01", 0x60040020),  # step 4: position 6004h:00, 32 bit
    ("0x1A00:02", 0x51220108),  # sys register 5122h:01, 8 bit
    ("0x1A00:03", 0x51220208),  # flag 0 register 5122h:02, 8 bit
    ("0x1A00:00", 3),  # step 5: mapping on, 3 entries
    ("0x1800:01", 0x181),  # step 6: PDO on
]


def _writes(pairs: list[tuple[str, int]]) -> list[tuple[ObjRef, int]]:
    return [(ObjRef.parse(o), v) for o, v in pairs]


def test_ap05_tpdo2_of_the_manual_example_decodes_position_and_status_word() -> None:
    tpdos, _ = compile_node(load_profile("ap05"), 1)
    tpdo2 = next(c for c in tpdos if c.number == 2)
    assert tpdo2.cob_id == 0x281
    assert tpdo2.length == 8
    values = dict(zip(tpdo2.names, tpdo2.decode(AP05_TPDO2_NODE1), strict=True))
    assert values["position"] == 250
    assert values["status_word"] == 0x0401


def test_ap05_rpdo2_of_the_manual_example_encodes_set_point_and_control_word() -> None:
    _, rpdos = compile_node(load_profile("ap05"), 1)
    rpdo2 = next(c for c in rpdos if c.number == 2)
    assert rpdo2.cob_id == 0x301
    values = rpdo2.initial_values()
    values[rpdo2.index_of("set_point2")] = 300
    values[rpdo2.index_of("control_word")] = 0x0200
    assert rpdo2.encode(values) == AP05_RPDO2_NODE1


def test_unnamed_dummy_entries_are_decoded_and_dropped() -> None:
    tpdos, _ = compile_node(load_profile("posi_plus"), 1, 0x02)
    tpdo1 = next(c for c in tpdos if c.number == 1)
    # manual 002 5, 2005h type 2: position (0-3), speed 2002h (4-5), 00h 00h (6-7)
    assert tpdo1.names == ("position", "speed")
    assert tpdo1.decode(bytes.fromhex("10270000F6FF0000")) == (10000, -10)


def test_short_frame_raises_and_longer_frame_decodes_the_mapped_bytes() -> None:
    tpdos, _ = compile_node(load_profile("sgh10"), 1)
    tpdo1 = tpdos[0]
    with pytest.raises(ValueError, match="mapping needs 6"):
        tpdo1.decode(b"\x01\x02")
    assert tpdo1.decode(bytes.fromhex("0100000002000000")) == tpdo1.decode(
        bytes.fromhex("010000000200")
    )


def test_bit_packed_mapping_uses_the_slow_path_with_signed_values() -> None:
    lp = load_profile("msk5000")
    writes = _writes(
        [("0x1800:01", 0x80000181), ("0x1A00:00", 0), ("0x1A00:01", 0x60300110),
         ("0x1A00:02", 0x51220104), ("0x1A00:00", 2), ("0x1800:01", 0x181)]
    )  # fmt: skip
    tpdos, _ = compile_node(lp, 1, None, writes)
    tpdo1 = next(c for c in tpdos if c.number == 1)
    assert tpdo1.length == 3  # 16 + 4 bits
    # speed -2 (FFFEh), then the low nibble of byte 2 = 5122h:01 (4 bits)
    assert tpdo1.decode(bytes([0xFE, 0xFF, 0xA5])) == (-2, 0x5)


def test_msk5000_remap_by_the_manual_steps_is_what_the_decoder_follows() -> None:
    lp = load_profile("msk5000")
    tpdos, _ = compile_node(lp, 1, None, _writes(MSK_REMAP_NODE1))
    tpdo1 = next(c for c in tpdos if c.number == 1)
    assert tpdo1.cob_id == 0x181
    assert tpdo1.names == ("position", "sys_register", "flag0_register")
    assert tpdo1.length == 6
    assert tpdo1.decode(bytes.fromhex("E803000002 01".replace(" ", ""))) == (1000, 2, 1)
    tpdo2 = next(c for c in tpdos if c.number == 2)
    assert tpdo2.names == ("position", "speed")  # untouched: the profile layout


def test_pdo_left_invalid_by_the_writes_is_not_decoded() -> None:
    lp = load_profile("msk5000")
    tpdos, _ = compile_node(lp, 1, None, _writes([("0x1801:01", 0x80000281)]))
    assert [c.number for c in tpdos] == [1]


def test_cob_id_written_by_the_boot_configuration_moves_the_pdo() -> None:
    lp = load_profile("sgh10")
    tpdos, _ = compile_node(lp, 1, None, _writes([("0x1800:01", 0x80000181), ("0x1800:01", 0x1A1)]))
    assert next(c for c in tpdos if c.number == 1).cob_id == 0x1A1


def test_a_pdo_outside_the_layout_needs_both_cob_id_and_mapping() -> None:
    lp = load_profile("msk5000")
    only_map = apply_pdo_writes(
        lp, "tpdo", [], 1, _writes([("0x1A02:01", 0x60040020), ("0x1A02:00", 1)])
    )
    assert only_map == []
    both = apply_pdo_writes(
        lp,
        "tpdo",
        [],
        1,
        _writes([("0x1A02:01", 0x60040020), ("0x1A02:00", 1), ("0x1802:01", 0x381)]),
    )
    assert [(p.number, p.cob_id, p.add_node_id) for p in both] == [(3, 0x381, False)]
    assert [str(e.object) for e in both[0].mapping] == ["0x6004:00"]


def test_mapping_enabled_with_an_unwritten_entry_is_refused() -> None:
    lp = load_profile("msk5000")
    with pytest.raises(PdoMappingError, match="sub-index 3"):
        compile_node(lp, 1, None, _writes([("0x1A00:00", 0), ("0x1A00:01", 0x60040020),
                                           ("0x1A00:00", 3)]))  # fmt: skip


def test_mapping_longer_than_eight_bytes_is_refused() -> None:
    lp = load_profile("msk5000")
    writes = [("0x1A00:00", 0)] + [(f"0x1A00:0{i}", 0x60040020) for i in range(1, 4)]
    with pytest.raises(PdoMappingError, match="more than 8 bytes"):
        compile_node(lp, 1, None, _writes([*writes, ("0x1A00:00", 3)]))


def test_rpdo_mapping_writes_change_the_encoder() -> None:
    lp = load_profile("ap05")
    writes = _writes(
        [("0x1401:01", 0x80000301), ("0x1601:00", 0), ("0x1601:01", 0x5F0C0010),
         ("0x1601:02", 0x5F160120), ("0x1601:00", 2), ("0x1401:01", 0x301)]
    )  # fmt: skip
    _, rpdos = compile_node(lp, 1, None, writes)
    rpdo2 = next(c for c in rpdos if c.number == 2)
    values = rpdo2.initial_values()
    values[rpdo2.index_of("control_word")] = 0x0200
    values[rpdo2.index_of("set_point2")] = 300
    assert rpdo2.encode(values) == bytes.fromhex("00022C010000")


def test_remappable_tpdo_feature_names_the_pdo_objects() -> None:
    lp = load_profile("msk5000")
    assert pdo_objects(lp, "tpdo", 1) == (0x1800, 0x1A00)
    assert pdo_objects(lp, "tpdo", 2) == (0x1801, 0x1A01)
    assert pdo_objects(lp, "rpdo", 2) == (0x1401, 0x1601)


def test_config_with_a_remap_the_decoder_cannot_follow_is_refused_at_load() -> None:
    from canopen_gateway.config import ConfigError
    from tests.helpers import make_config

    node = {
        "name": "magnet",
        "node_id": 2,
        "profile": "msk5000",
        "sdo": [
            {"object": "0x1A00:00", "value": 0},
            {"object": "0x1A00:01", "value": "0x60040020"},
            {"object": "0x1A00:00", "value": 3},
        ],
    }
    with pytest.raises(ConfigError) as err:
        make_config([node])
    assert err.value.problems == [
        "<memory>: nodes[0]: TPDO1: mapping sub-index 3 is enabled but never written"
    ]
