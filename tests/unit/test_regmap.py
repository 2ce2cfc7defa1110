"""The Modbus register map: layouts, types, word orders, bits, overrides, the rendered table, and
how values become registers (pure: no server, no bus)."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import pytest

from canopen_gateway.config import ConfigError
from canopen_gateway.modbus.protocol import from_registers, register_encoder, to_registers
from canopen_gateway.northbound.regmap import NODE_DIAG, Point, RegisterMap, build_register_map
from tests.helpers import load_checked_config as load_config
from tests.helpers import parse_checked_config as parse_config
from tests.helpers import with_nodes

ROOT = Path(__file__).resolve().parents[2]
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
ROTARY = {"name": "rotary", "node_id": 3, "profile": "posi_plus"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}


def regmap(*nodes: dict[str, Any], **modbus: Any) -> RegisterMap:
    raw = {"nodes": list(nodes), "modbus": modbus}
    return build_register_map(*with_nodes(parse_config(raw, environ={})))


def point(rm: RegisterMap, unit: int, table: str, address: int) -> Point:
    p = rm.lookup(unit, table, address)  # type: ignore[arg-type]
    assert p is not None, f"nothing at {table} {address} of unit {unit}"
    return p


# ---------------------------------------------------------------------- layouts
def test_default_layout_gives_each_node_its_node_id_as_unit_plus_gateway_unit_247() -> None:
    rm = regmap(WIRE, DISPLAY)
    assert rm.units == {247: None, 1: "wire", 125: "display"}
    assert point(rm, 247, "ir", 0).name == "bus_state"
    assert point(rm, 247, "ir", 18).name == "nodes_operational"


def test_each_node_unit_has_diagnostics_nmt_register_and_process_data_at_100() -> None:
    rm = regmap(WIRE)
    for off, name, _, _ in NODE_DIAG:
        assert point(rm, 1, "ir", off).name == name
    assert point(rm, 1, "ir", 12).name == "last_sdo_abort"
    assert [point(rm, 1, "di", a).name for a in range(4)] == [
        "alive",
        "operational",
        "link_ok",
        "error_active",
    ]
    nmt = point(rm, 1, "hr", 0)
    assert (nmt.kind, nmt.access) == ("nmt", "rw")
    assert point(rm, 1, "ir", 100).name == "position"
    assert point(rm, 1, "ir", 101).name == "position"
    assert point(rm, 1, "ir", 102).name == "velocity"
    assert point(rm, 1, "hr", 100).name == "work_area_1_state"


def test_unit_id_override_moves_a_node_to_another_unit() -> None:
    rm = regmap({**WIRE, "modbus": {"unit_id": 9}})
    assert rm.units == {247: None, 9: "wire"}
    assert point(rm, 9, "ir", 100).name == "position"


def test_flat_layout_puts_gateway_at_0_and_node_k_at_k_times_stride_in_one_unit() -> None:
    rm = regmap(WIRE, DISPLAY, layout="flat", flat_unit_id=7, flat_stride=300)
    assert rm.units == {7: None}
    assert point(rm, 7, "ir", 0).name == "bus_state"
    wire = point(rm, 7, "ir", 300 + 100)
    assert (wire.node, wire.name) == ("wire", "position")
    assert point(rm, 7, "ir", 300 + 12).name == "last_sdo_abort"
    display = point(rm, 7, "ir", 600 + 100)
    assert (display.node, display.name) == ("display", "position")
    cw = point(rm, 7, "hr", 600 + 106)
    assert (cw.node, cw.name) == ("display", "control_word")
    assert point(rm, 7, "hr", 600).kind == "nmt"


def test_flat_layout_with_a_stride_too_small_for_a_node_is_a_config_error() -> None:
    with pytest.raises(ConfigError) as exc:
        parse_config(
            {"nodes": [WIRE], "modbus": {"layout": "flat", "flat_stride": 150}}, environ={}
        )
    assert any("modbus.flat_stride" in line and "wire" in line for line in exc.value.problems)


# ---------------------------------------------------------------------- types
def test_register_types_and_counts_follow_the_signal_types() -> None:
    rm = regmap(WIRE, DISPLAY)
    position = point(rm, 1, "ir", 100)
    assert (position.type, position.count, position.scale) == ("int32", 2, 0.1)
    assert (point(rm, 1, "ir", 102).type, point(rm, 1, "ir", 102).count) == ("int16", 1)
    # uint8 configuration objects are served as uint16
    op_mode = next(p for p in rm.points if p.node == "display" and p.name == "operating_mode")
    assert (op_mode.type, op_mode.count, op_mode.table, op_mode.transport) == (
        "uint16",
        1,
        "hr",
        "sdo",
    )
    # a 5-character VISIBLE_STRING takes 3 registers
    name = next(p for p in rm.points if p.node == "wire" and p.name == "device_name")
    assert (name.type, name.count, name.type_text) == ("string", 3, "string[6]")
    chars = point(rm, 125, "hr", 102)
    assert (chars.name, chars.type, chars.count, chars.access) == (
        "set_point1_chars_5_6",
        "string",
        1,
        "rw",
    )


def test_as_float_serves_an_engineering_float32_of_raw_times_scale() -> None:
    rm = regmap({**WIRE, "signals": {"position": {"as_float": True}}})
    p = point(rm, 1, "ir", 100)
    assert (p.type, p.count, p.engineering) == ("float32", 2, True)
    assert p.scaling == "float32 = raw x 0.1 + 0"
    assert to_registers(12345, p) == [0x449A, 0x5000]  # 1234.5 as IEEE 754 single
    assert from_registers([0x449A, 0x5000], p) == 12345


def test_gateway_word_order_applies_to_every_point_and_a_point_may_override_it() -> None:
    rm = regmap(
        {**WIRE, "signals": {"velocity": {"as_float": True, "word_order": "big"}}},
        word_order="little",
    )
    position, velocity = point(rm, 1, "ir", 100), point(rm, 1, "ir", 102)
    assert position.word_order == "little"
    assert position.type_text == "int32 (low word first)"
    assert velocity.word_order == "big"
    assert velocity.type_text == "float32 (high word first)"
    assert point(rm, 1, "ir", 12).word_order == "big", "diagnostics keep the Modbus default"


def test_pinned_address_places_a_signal_where_the_plc_expects_it() -> None:
    rm = regmap({**WIRE, "signals": {"velocity": {"address": 150}}})
    assert point(rm, 1, "ir", 150).name == "velocity"
    assert rm.lookup(1, "ir", 102) is None


def test_a_pdo_signal_outside_the_node_pdo_layout_has_no_register() -> None:
    default = regmap(ROTARY)
    assert not [p for p in default.points if p.name == "speed"]
    type2 = regmap({**ROTARY, "pdo_variant": 0x02})
    speed = point(type2, 3, "ir", 102)
    assert (speed.name, speed.type) == ("speed", "int16")


# ---------------------------------------------------------------------- bits
def test_bits_of_a_read_only_status_word_are_discrete_inputs_at_start_plus_bit() -> None:
    rm = regmap(DISPLAY)
    guarding = point(rm, 125, "di", 100 + 8)
    assert (guarding.name, guarding.bit, guarding.access) == ("status_word", 8, "ro")
    assert guarding.description.startswith("guarding_bit")
    # two meanings of one bit (AP05 manual 5.3.3 table 28) share the address
    assert point(rm, 125, "di", 103).description.startswith(
        "target_window2_dynamic / set_point2_acknowledged"
    )


def test_bits_of_a_writable_word_are_coils_and_every_bit_has_an_address() -> None:
    rm = regmap(DISPLAY)
    coils = [point(rm, 125, "co", 100 + b) for b in range(16)]
    assert {(c.name, c.access, c.transport) for c in coils} == {("control_word", "rw", "pdo")}
    assert [c.bit for c in coils] == list(range(16))
    params = point(rm, 125, "co", 116)
    assert (params.name, params.bit, params.transport) == ("operating_parameters", 0, "sdo")


def test_words_without_single_named_bits_get_no_bit_addresses() -> None:
    rm = regmap(DISPLAY)
    assert not [p for p in rm.points if p.kind == "bit" and p.name == "can_error_counters"]


# ---------------------------------------------------------------------- rendering
def test_csv_has_one_row_per_value_and_per_bit_with_the_documented_columns() -> None:
    rm = regmap(DISPLAY)
    rows = list(csv.DictReader(io.StringIO(rm.to_csv())))
    assert list(rows[0]) == [
        "unit_id",
        "table",
        "address",
        "type",
        "access",
        "node",
        "signal",
        "unit",
        "scaling",
        "description",
        "network",
    ]
    position = next(r for r in rows if r["signal"] == "position")
    assert (position["unit_id"], position["table"], position["address"]) == (
        "125",
        "input register",
        "100-101",
    )
    assert position["type"] == "int32 (high word first)"
    bit8 = next(r for r in rows if r["signal"] == "status_word.bit8")
    assert (bit8["table"], bit8["address"]) == ("discrete input", "108")
    assert len(rows) == len(rm.points)


def test_markdown_groups_the_bits_of_a_word_in_one_row() -> None:
    md = regmap(DISPLAY).to_markdown()
    line = next(x for x in md.splitlines() if "| status_word |" in x and "discrete input" in x)
    assert "| 100-115 | bits[16] |" in line
    assert "8 guarding_bit" in line
    assert md.splitlines()[1] == "|---|---|---|---|---|---|---|---|---|---|"


def test_register_table_in_docs_is_the_one_the_cli_prints_for_the_demo() -> None:
    doc = (ROOT / "docs/modbus.md").read_text(encoding="utf-8")
    start = doc.index("<!-- register-table:begin -->") + len("<!-- register-table:begin -->\n")
    end = doc.index("<!-- register-table:end -->")
    expected = build_register_map(*with_nodes(load_config(ROOT / "config/demo.yaml", environ={}))).to_markdown()
    assert doc[start:end] == expected, (
        "docs/modbus.md is out of date: regenerate the table with "
        "`canopen-gateway registers -c config/demo.yaml`"
    )


# ---------------------------------------------------------------------- values <-> registers
def _pt(type_: str, count: int, **kw: Any) -> Point:
    return Point(1, "ir", 100, count, "signal", "x", type_, "rw", "n", **kw)


@pytest.mark.parametrize(
    ("type_", "count", "value", "regs"),
    [
        ("int16", 1, -2, [0xFFFE]),
        ("uint16", 1, 0xBEEF, [0xBEEF]),
        ("int32", 2, -100000, [0xFFFE, 0x7960]),
        ("uint32", 2, 0x12345678, [0x1234, 0x5678]),
        ("float32", 2, 1.5, [0x3FC0, 0x0000]),
        ("int64", 4, -1, [0xFFFF] * 4),
        ("uint64", 4, 0x0102030405060708, [0x0102, 0x0304, 0x0506, 0x0708]),
    ],
)
def test_numbers_are_big_endian_words_by_default_and_round_trip(
    type_: str, count: int, value: Any, regs: list[int]
) -> None:
    p = _pt(type_, count)
    assert to_registers(value, p) == regs
    assert from_registers(regs, p) == value


def test_little_word_order_puts_the_low_word_first() -> None:
    p = _pt("uint32", 2, word_order="little")
    assert to_registers(0x12345678, p) == [0x5678, 0x1234]
    assert from_registers([0x5678, 0x1234], p) == 0x12345678
    f = _pt("float32", 2, word_order="little")
    assert to_registers(1.5, f) == [0x0000, 0x3FC0]


def test_strings_put_the_first_character_in_the_high_byte_and_pad_with_nul() -> None:
    p = _pt("string", 3)
    assert to_registers("SGH10", p) == [0x5347, 0x4831, 0x3000]
    assert to_registers(b"AB", _pt("string", 1)) == [0x4142]
    assert from_registers([0x5347, 0x4831, 0x3000], p) == b"SGH10"


@pytest.mark.parametrize("regs", [[0x7FC0, 0x0000], [0x7F80, 0x0000]], ids=["nan", "infinity"])
def test_an_engineering_float_that_is_not_a_finite_number_cannot_become_a_raw_value(
    regs: list[int],
) -> None:
    p = _pt("float32", 2, engineering=True, scale=0.1)
    with pytest.raises((ValueError, OverflowError)):
        from_registers(regs, p)


@pytest.mark.parametrize(
    ("type_", "count", "engineering"),
    [("int16", 1, False), ("uint16", 1, False), ("int32", 2, False), ("uint32", 2, False),
     ("float32", 2, False), ("float32", 2, True), ("int64", 4, False), ("uint64", 4, False),
     ("string", 4, False)],
)  # fmt: skip
@pytest.mark.parametrize("word_order", ["big", "little"])
def test_register_encoder_is_to_registers_made_once_per_point(
    type_: str, count: int, engineering: bool, word_order: str
) -> None:
    """The per-point encoder of image reads gives what ``to_registers`` gives, for every type,
    word order and scaling, at the edges of each range (values wider than the type wrap)."""
    p = _pt(type_, count, word_order=word_order, engineering=engineering, scale=0.1, offset=2.0)
    encode = register_encoder(p)
    values: list[Any] = ["AB", b"xyz"] if type_ == "string" else [
        0, 1, -1, 0x7FFF, -0x8000, 0xFFFF, 0x10000, 0x7FFFFFFF, -0x80000000, 0xFFFFFFFF,
        0x1_0000_0001, -0x1_0000_0001, True, 3.7, -3.7]
    for v in values:
        assert encode(v) == to_registers(v, p), (p.type, p.word_order, v)
