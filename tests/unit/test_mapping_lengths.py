"""Mapping entries whose length is not their object's type's (CiA 301 7.5.2.36): a float of
another length is never served, an integer is carried at the narrower of the two widths both
ways (decoded sign-extended from it, writes range-checked against it), the output image changes
only after every RPDO it touches encodes; and two spellings of one EDS sub-section."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_gateway.bus.node.outputs import OutputImage
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.commands import check_value
from canopen_gateway.config import NodeConfig
from canopen_gateway.eds import lint, load_eds
from canopen_gateway.errors import ValueOutOfRange
from canopen_gateway.pdo.codec import (
    Field,
    FieldValueError,
    RpdoCodec,
    TpdoCodec,
    compile_fields,
    compile_node,
)
from canopen_gateway.profiles import load_node_profile
from canopen_gateway.profiles.schema import Pdo
from tests.helpers import edited_copy, line_of

DATA = Path(__file__).resolve().parents[1] / "data" / "eds"
IO = DATA / "io401.eds"
FLOW = DATA / "measure.eds"





def node(eds: Path) -> NodeConfig:
    return NodeConfig.model_validate({"name": "n", "node_id": 5, "eds": str(eds)})


# --------------------------------------------------------------------------- a float's length


def test_real32_mapped_in_16_bits_is_not_served_and_warned_with_file_line_and_pdo(tmp_path: Path) -> None:
    # measure.eds TPDO1: temperatur 2000h REAL32 /32, durchfluss 2001h REAL32 /32 -> 2000h /16
    eds = edited_copy(tmp_path, FLOW, "DefaultValue=0x20000020", "DefaultValue=0x20000010")
    lp = load_node_profile(node(eds).setup)
    names = {s.name for s in lp.profile.signals}
    assert "temperatur" not in names and "durchfluss" in names
    at = f"{eds}:{line_of(eds, '[1A00sub1]')}: [1A00sub1]: TPDO1 entry 0x2000:00/16"
    assert any(w.startswith(at) and "REAL32 (32 bit)" in w and "no value: skipped" in w for w in lp.warnings), lp.warnings  # fmt: skip
    (tpdo1, *_), _ = compile_node(lp, 5)
    assert tpdo1.names == ("durchfluss",)
    # 16 bits of a temperature the device cannot have meant, then the flow at bit offset 16
    assert tpdo1.decode(struct.pack("<Hf", 16812, -3.25)) == (-3.25,)
    result = lint(load_eds(eds))
    assert result.errors == ()
    assert any(str(w).startswith(at) and "no value: skipped" in str(w) for w in result.warnings)


def test_a_float_of_another_length_decodes_as_nothing_on_both_paths() -> None:
    lp = load_node_profile(node(FLOW).setup)
    for fmt, entries in (("aligned", [(0x2000, 16), (0x2001, 32)]), ("bits", [(0x2000, 12), (0x2001, 32)])):
        pdo = Pdo(number=1, mapping=[{"object": ObjRef(i, 0), "bits": b} for i, b in entries])
        fields = compile_fields(lp, pdo)
        assert [f.signal for f in fields] == [None, "durchfluss"], fmt
        codec = TpdoCodec(0x186, 1, fields)
        word = 0x7FF | int.from_bytes(struct.pack("<f", 21.5), "little") << fields[1].bit_offset
        assert codec.decode(word.to_bytes(codec.length, "little")) == (21.5,), fmt


# --------------------------------------------------------------------------- an integer's length


def field(bits: int, offset: int, signed: bool, type_bits: int, name: str = "v") -> Field:
    return Field(ObjRef(0x6411, 1), bits, offset, name, signed, False, False, type_bits)


def test_integer16_in_12_bits_decodes_sign_extended_and_refuses_what_12_bits_cannot_carry() -> None:
    fields = [field(16, 0, False, 16, "out"), field(12, 16, True, 16, "analogue")]
    rpdo = RpdoCodec(0x305, 2, fields)
    tpdo = TpdoCodec(0x185, 1, fields)
    assert rpdo.encode([0, -100]) == bytes.fromhex("00009C0F")
    assert tpdo.decode(bytes.fromhex("00009C0F")) == (0, -100)
    assert tpdo.decode(bytes.fromhex("0000FF07")) == (0, 2047)
    with pytest.raises(FieldValueError) as exc:
        rpdo.encode([0, 3000])  # before: silently sent as -1096
    assert exc.value.allowed == "an integer -2048..2047 (12 bits)"
    assert "analogue" in str(exc.value)


def test_integer32_in_16_aligned_bits_is_refused_not_a_struct_error() -> None:
    rpdo = RpdoCodec(0x205, 1, [field(16, 0, True, 32, "set_point"), field(16, 16, False, 16, "ctrl")])
    assert rpdo.encode([-2, 7]) == struct.pack("<hH", -2, 7)
    with pytest.raises(FieldValueError):
        rpdo.encode([40000, 7])  # before: struct.error from the precompiled format


def test_an_integer_wider_than_its_type_carries_the_type_in_its_low_bits() -> None:
    f = field(16, 0, True, 8)
    assert f.value_range() == (-128, 127)
    codec = TpdoCodec(0x185, 1, [f])
    assert codec.decode(bytes.fromhex("FF00")) == (-1,)
    assert RpdoCodec(0x205, 1, [f]).encode([-1]) == bytes.fromhex("FFFF")


@st.composite
def layouts(draw: Any) -> tuple[list[Field], list[Any]]:
    """Fields of 1..64 bits at every offset (a raw padding entry first), widths up to 64 in all,
    each with a value it can carry: integers (signed or not, narrower or as wide as their type),
    whole-byte text, REAL32/REAL64."""
    pad = draw(st.integers(0, 63))
    fields: list[Field] = []
    values: list[Any] = []
    offset = 0
    if pad:
        fields.append(Field(ObjRef(0x0007, 0), pad, 0, None, False, False, False, 32))
        values.append(0)
        offset = pad
    while offset < 64:
        bits = draw(st.integers(1, 64 - offset))
        obj, name = ObjRef(0x2000 + len(fields), 0), f"s{len(fields)}"
        kind = draw(st.sampled_from(["int", "text", "float"]))
        if kind == "float" and 64 - offset >= 32:
            bits = draw(st.sampled_from([b for b in (32, 64) if b <= 64 - offset]))
            fields.append(Field(obj, bits, offset, name, False, True, False, bits))
            width = "f" if bits == 32 else "d"
            value = draw(st.floats(width=bits, allow_nan=False))  # type: ignore[arg-type]
            values.append(struct.unpack("<" + width, struct.pack("<" + width, value))[0])
        elif kind == "text" and bits >= 8:
            fields.append(Field(obj, bits, offset, name, False, False, True, None))
            values.append(draw(st.binary(min_size=bits // 8, max_size=bits // 8)))
        else:
            signed = draw(st.booleans()) and bits > 1
            type_bits = draw(st.sampled_from([b for b in (8, 16, 24, 32, 40, 48, 56, 64) if b >= bits] + [bits]))
            f = Field(obj, bits, offset, name, signed, False, False, type_bits)
            lo, hi = f.value_range()  # type: ignore[misc]
            fields.append(f)
            values.append(draw(st.integers(lo, hi)))
        offset += bits
        if draw(st.booleans()):
            break
    return fields, values


@settings(max_examples=300, deadline=None)
@given(layouts())
def test_unaligned_widths_round_trip_exactly(layout: tuple[list[Field], list[Any]]) -> None:
    fields, values = layout
    frame = RpdoCodec(0x200, 1, fields).encode(values)
    decoded = TpdoCodec(0x180, 1, fields).decode(frame)
    assert list(decoded) == [v for f, v in zip(fields, values, strict=True) if f.signal]


@settings(max_examples=200, deadline=None)
@given(layouts(), st.data())
def test_a_value_outside_the_mapped_width_is_refused_by_the_encoder(
    layout: tuple[list[Field], list[Any]], data: Any
) -> None:
    fields, values = layout
    ints = [i for i, f in enumerate(fields) if f.signal and f.value_range() is not None]
    if not ints:
        return
    i = data.draw(st.sampled_from(ints))
    lo, hi = fields[i].value_range()  # type: ignore[misc]
    values[i] = data.draw(st.sampled_from([lo - 1, hi + 1]))
    with pytest.raises(FieldValueError):
        RpdoCodec(0x200, 1, fields).encode(values)


# --------------------------------------------------------------------------- the output image


def test_output_image_refuses_a_value_its_rpdo_cannot_carry_and_changes_nothing() -> None:
    rpdo = RpdoCodec(0x305, 2, [field(16, 0, False, 16, "out"), field(12, 16, True, 16, "analogue")])
    image = OutputImage("io", [rpdo], keepalive_s=0.5)
    assert image.set({None: {"analogue": -100}}) == [2]
    image.frame(2, 0.0)
    with pytest.raises(ValueOutOfRange) as exc:
        image.set({None: {"out": 5, "analogue": 3000}})
    assert exc.value.name == "analogue" and "-2048..2047" in exc.value.allowed
    assert image.snapshot() == {2: (0, -100)}
    # nothing left behind: the keep-alive and the next write go out
    assert image.keepalive(1.0).data == bytes.fromhex("00009C0F")
    assert image.set({None: {"out": 5}}) == [2]
    assert image.frame(2, 2.0).data == bytes.fromhex("05009C0F")


def test_a_write_is_range_checked_against_the_mapped_width() -> None:
    lp = load_node_profile(node(IO).setup)
    sig = lp.profile.signal("analogue_output_1")
    assert check_value(sig, 3000) == 3000
    with pytest.raises(ValueOutOfRange) as exc:
        check_value(sig, 3000, mapped_bits=12)
    assert exc.value.allowed == "-2048..2047 (int16 mapped in 12 bits)"
    assert check_value(sig, -2048, mapped_bits=12) == -2048


# --------------------------------------------------------------------------- two spellings


def test_two_spellings_of_one_sub_section_the_first_counts_and_the_second_warns(tmp_path: Path) -> None:
    # io401.eds RPDO2 1601h sub 2 = 6411h:01/16; a second spelling [1601sub02] maps 6300h:01
    second = "[1601sub02]\nParameterName=Mapped object 2\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x63000110\nPDOMapping=0\n\n[1601sub3]"  # fmt: skip
    eds = edited_copy(tmp_path, IO, "[1601sub3]", second)
    loaded = load_eds(eds)
    assert loaded.od[0x1601][2].default == 0x64110110
    at = f"{eds}:{line_of(eds, '[1601sub02]')}: [1601sub02]: sub-index 02h again (first as [1601sub2] at line {line_of(eds, '[1601sub2]')}): ignored"  # fmt: skip
    assert at in [str(w) for w in loaded.warnings]
    assert at in [str(w) for w in lint(loaded).warnings]
    assert not any("SubNumber" in str(w) for w in loaded.warnings)  # 9 sub-indices, as it says
    assert loaded.line_of(ObjRef(0x1601, 2)) == line_of(eds, "[1601sub2]")
    lp = load_node_profile(node(eds).setup)
    assert [(str(e.object), e.bits) for e in lp.profile.rpdos[1].mapping] == [("0x6300:01", 16), ("0x6411:01", 16)]  # fmt: skip


def test_two_spellings_the_padded_one_first_counts_too(tmp_path: Path) -> None:
    eds = edited_copy(tmp_path, IO, "[1601sub2]", "[1601sub02]")
    later = "[1601sub2]\nParameterName=Mapped object 2\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x63000110\nPDOMapping=0\n\n[1601sub3]"  # fmt: skip
    eds = edited_copy(tmp_path, eds, "[1601sub3]", later, "twice.eds")
    loaded = load_eds(eds)
    assert loaded.od[0x1601][2].default == 0x64110110
    assert any("sub-index 02h again (first as [1601sub02]" in str(w) for w in loaded.warnings)
    assert loaded.line_of(ObjRef(0x1601, 2)) == line_of(eds, "[1601sub02]")


def test_a_real32_beyond_its_range_is_refused_before_the_image_changes() -> None:
    lp = load_node_profile(node(FLOW).setup)
    sig = lp.profile.signal("durchfluss")
    with pytest.raises(ValueOutOfRange):
        check_value(sig, 1e39)
    assert check_value(sig, -3.25) == -3.25
    rpdo = RpdoCodec(0x206, 1, [Field(ObjRef(0x2100, 0), 32, 0, "set_point", False, True, False, 32)])
    image = OutputImage("flow", [rpdo])
    image.set({None: {"set_point": 1.5}})
    with pytest.raises(ValueOutOfRange):
        image.set({None: {"set_point": 1e39}})  # before: OverflowError from struct, image changed
    assert image.snapshot() == {1: (1.5,)}
