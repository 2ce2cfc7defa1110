"""The CiA 301 basic types beyond 32 bits and the time types, each codec both ways: SDO bytes,
PDO codecs, Modbus registers (both word orders), Zenoh values; the register map of a device
with them; an object that a TPDO and an RPDO both carry (an input and an output)."""

from __future__ import annotations

import struct
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canopen_gateway.ascii.values import format_plain
from canopen_gateway.canopen.cia301 import (
    MS_PER_DAY,
    TIME_EPOCH_UNIX_MS,
    time_fields,
    time_ms,
    time_word,
)
from canopen_gateway.config import ConfigError
from canopen_gateway.device.values import decode_value, encode_value
from canopen_gateway.image import Quality, SignalValue
from canopen_gateway.modbus.protocol import from_registers, to_registers
from canopen_gateway.northbound.keys import all_keys
from canopen_gateway.northbound.regmap import Point, build_register_map
from canopen_gateway.northbound.scaling import Scaling, engineering, time_of_text, time_text, to_raw
from canopen_gateway.pdo.codec import compile_node
from canopen_gateway.profiles import load_node_profile
from canopen_gateway.profiles.schema import Signal
from canopen_gateway.web.trends import is_trend_signal
from canopen_gateway.web.views import SignalMeta
from canopen_gateway.zenoh_bridge.payloads import pdo_json, value_json
from tests.helpers import parse_checked_config, with_nodes

DATA = Path(__file__).resolve().parents[1] / "data" / "eds"
NODE = {"name": "dev", "node_id": 5, "profile": str(DATA / "types.yaml")}
IDENTITY = Scaling("", 1.0, 0.0)

#: type -> (bits, signed) of the integers beyond 32 bits (CiA 301 7.1.4.3 / 7.1.4.4)
WIDE_INTS = {"int40": (40, True), "int48": (48, True), "int56": (56, True),
             "uint40": (40, False), "uint48": (48, False), "uint56": (56, False)}  # fmt: skip


def _ints(bits: int, signed: bool) -> st.SearchStrategy[int]:
    return st.integers(-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else st.integers(0, (1 << bits) - 1)


def cfg() -> Any:
    return parse_checked_config({"nodes": [NODE]}, environ={})


# --------------------------------------------------------------------------- SDO bytes
@pytest.mark.parametrize("type_", sorted(WIDE_INTS))
@settings(max_examples=50, deadline=None)
@given(data=st.data())
def test_wide_integers_travel_by_sdo_in_their_own_bytes_both_ways(type_: str, data: st.DataObject) -> None:
    bits, signed = WIDE_INTS[type_]
    v = data.draw(_ints(bits, signed))
    raw = encode_value(v, type_)
    assert raw == v.to_bytes(bits // 8, "little", signed=signed)
    assert decode_value(raw, type_) == v


@pytest.mark.parametrize(("type_", "value"), [("int40", 1 << 39), ("uint48", -1), ("uint56", 1 << 56), ("int24", 1 << 23)])  # fmt: skip
def test_an_sdo_value_too_wide_for_its_type_is_a_value_error(type_: str, value: int) -> None:
    with pytest.raises(ValueError, match=f"does not fit {type_}"):
        encode_value(value, type_)


@settings(max_examples=100, deadline=None)
@given(st.floats(allow_nan=False))
def test_real64_travels_by_sdo_as_eight_ieee_bytes(v: float) -> None:
    assert encode_value(v, "float64") == struct.pack("<d", v)
    assert decode_value(struct.pack("<d", v), "float64") == v


def test_time_of_day_by_sdo_is_its_48_bit_word() -> None:
    # CiA 301 7.1.6.5: 4 bytes ms (28 bits + 4 reserved), then 2 bytes days since 1984-01-01
    data = (30_600_250).to_bytes(4, "little") + (15671).to_bytes(2, "little")
    word = decode_value(data, "time_of_day")
    assert time_fields(word) == (15671, 30_600_250)
    assert encode_value(word, "time_of_day") == data
    assert decode_value(data, "time_difference") == word


# --------------------------------------------------------------------------- time words
@settings(max_examples=200, deadline=None)
@given(st.integers(0, (0xFFFF + 1) * MS_PER_DAY - 1))
def test_time_word_counts_days_and_milliseconds(total_ms: int) -> None:
    w = time_word(total_ms)
    days, ms = time_fields(w)
    assert ms < MS_PER_DAY and days * MS_PER_DAY + ms == total_ms == time_ms(w)
    assert w >> 28 & 0xF == 0  # the reserved bits stay 0


@pytest.mark.parametrize("total_ms", [-1, (0xFFFF + 1) * MS_PER_DAY])
def test_time_beyond_the_word_is_refused(total_ms: int) -> None:
    with pytest.raises(ValueError, match="outside"):
        time_word(total_ms)


@settings(max_examples=200, deadline=None)
@given(st.datetimes(min_value=datetime(1984, 1, 1), max_value=datetime(2163, 1, 1)))
def test_time_of_day_as_iso_8601_both_ways(t: datetime) -> None:
    t = t.replace(microsecond=t.microsecond // 1000 * 1000, tzinfo=UTC)
    word = time_of_text(t.isoformat())
    assert datetime.fromisoformat(time_text(word)) == t
    assert time_of_text(time_text(word)) == word


def test_the_time_of_day_epoch_is_1984_01_01_utc_and_iso_text_is_utc() -> None:
    assert time_text(0) == "1984-01-01T00:00:00.000Z"
    assert TIME_EPOCH_UNIX_MS == int(datetime(1984, 1, 1, tzinfo=UTC).timestamp() * 1000)
    assert time_of_text("2026-11-27T09:30:00.250+01:00") == 15671 << 32 | 30_600_250
    assert time_of_text("2026-11-27T08:30:00.250") == 15671 << 32 | 30_600_250  # no zone: UTC


@pytest.mark.parametrize("text", ["yesterday", "1983-12-31T23:59:59Z", "2026-11-27T08:30:00.0001Z"])
def test_a_time_of_day_that_is_no_time_of_the_epoch_is_refused(text: str) -> None:
    with pytest.raises(ValueError):
        time_of_text(text)


# --------------------------------------------------------------------------- Modbus registers
def _point(type_: str, count: int, word_order: str = "big") -> Point:
    return Point(5, "ir", 100, count, "signal", "x", type_, "ro", "dev", word_order=word_order)  # type: ignore[arg-type]


@pytest.mark.parametrize("order", ["big", "little"])
@settings(max_examples=100, deadline=None)
@given(v=st.floats(allow_nan=False))
def test_real64_is_four_registers_in_the_word_order(order: str, v: float) -> None:
    p = _point("float64", 4, order)
    regs = to_registers(v, p)
    words = list(struct.unpack(">4H", struct.pack(">d", v)))
    assert regs == (words if order == "big" else words[::-1])
    assert from_registers(regs, p) == v


@pytest.mark.parametrize("order", ["big", "little"])
@settings(max_examples=100, deadline=None)
@given(v=_ints(48, True))
def test_integer48_is_an_int64_in_four_registers(order: str, v: int) -> None:
    p = _point("int64", 4, order)
    regs = to_registers(v, p)
    words = list(struct.unpack(">4H", struct.pack(">q", v)))
    assert regs == (words if order == "big" else words[::-1])
    assert from_registers(regs, p) == v


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 0xFFFF), st.integers(0, MS_PER_DAY - 1))
def test_time_of_day_is_unix_ms_and_time_difference_ms_in_four_registers(days: int, ms: int) -> None:
    word = days << 32 | ms
    tod, td = _point("time_of_day", 4), _point("time_difference", 4)
    assert to_registers(word, tod) == list(struct.unpack(">4H", struct.pack(">Q", TIME_EPOCH_UNIX_MS + days * MS_PER_DAY + ms)))  # fmt: skip
    assert to_registers(word, td) == list(struct.unpack(">4H", struct.pack(">Q", days * MS_PER_DAY + ms)))
    assert from_registers(to_registers(word, tod), tod) == word
    assert from_registers(to_registers(word, td), td) == word


def test_a_time_of_day_written_before_1984_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="1984"):
        from_registers([0, 0, 0, 1000], _point("time_of_day", 4))


# --------------------------------------------------------------------------- Zenoh values
def _sig(type_: str) -> Signal:
    return Signal(name="x", object="0x2003:00", type=type_, access="ro", transport="pdo")  # type: ignore[arg-type]


def test_zenoh_serves_a_time_of_day_as_iso_8601_and_a_time_difference_in_ms() -> None:
    word = 15671 << 32 | 30_600_250
    sv = SignalValue("x", word, 1.5, 1.0, 3)
    tod = value_json(_sig("time_of_day"), sv, Quality.GOOD, IDENTITY)
    assert '"value": "2026-11-27T08:30:00.250Z"' in tod
    td = value_json(_sig("time_difference"), sv, Quality.GOOD, IDENTITY)
    assert f'"value": {15671 * MS_PER_DAY + 30_600_250},' in td
    pdo = pdo_json([(_sig("time_of_day"), sv, Quality.GOOD, IDENTITY)], 1.5, 3)
    assert '"value": "2026-11-27T08:30:00.250Z"' in pdo
    assert engineering(_sig("float64"), 6.02214076e23, IDENTITY) == 6.02214076e23


def test_zenoh_writes_of_time_types_take_iso_text_and_milliseconds() -> None:
    assert to_raw(_sig("time_of_day"), "2026-11-27T08:30:00.250Z", IDENTITY) == 15671 << 32 | 30_600_250
    assert to_raw(_sig("time_difference"), 2 * MS_PER_DAY + 5, IDENTITY) == 2 << 32 | 5
    for bad in (12345, None):
        with pytest.raises(ValueError, match="ISO 8601"):
            to_raw(_sig("time_of_day"), bad, IDENTITY)
    for bad in ("12", 1.5, -1, True):
        with pytest.raises(ValueError):
            to_raw(_sig("time_difference"), bad, IDENTITY)


# --------------------------------------------------------------------------- PDO codecs
def test_tpdos_with_real64_integer48_and_time_of_day_decode_as_cia301_lays_them_out() -> None:
    lp = load_node_profile(cfg().nodes[0].setup)
    tpdos, rpdos = compile_node(lp, 5)
    t = {c.number: c for c in tpdos}
    assert t[1].names == ("energy",) and t[1].decode(struct.pack("<d", -2.5e-300)) == (-2.5e-300,)
    frame = (-(1 << 47)).to_bytes(6, "little", signed=True) + struct.pack("<H", 0xBEEF)
    assert t[2].decode(frame) == (-(1 << 47), 0xBEEF)
    tod = (30_600_250).to_bytes(4, "little") + (15671).to_bytes(2, "little")
    assert t[3].names == ("time_stamp", "command_number")
    assert t[3].decode(tod + b"\x07") == (15671 << 32 | 30_600_250, 7)
    (r,) = rpdos
    assert r.encode([9, -2]) == bytes([9]) + struct.pack("<i", -2)


# --------------------------------------------------------------------------- register map
def test_register_map_gives_each_type_its_registers_and_an_object_of_both_pdos_both_tables() -> None:
    rm = build_register_map(*with_nodes(cfg()))
    got = {(p.table, p.name): (p.address, p.type, p.count, p.access) for p in rm.node_points("dev") if p.kind == "signal"}
    assert got[("ir", "energy")] == (100, "float64", 4, "ro")
    assert got[("ir", "position")] == (104, "int64", 4, "ro")
    assert got[("ir", "time_stamp")] == (109, "time_of_day", 4, "ro")
    # 2010h: RPDO1 (holding register, the output) and TPDO3 (input register, the device's value)
    assert got[("ir", "command_number")] == (113, "uint16", 1, "ro")
    assert got[("hr", "command_number")][1:] == ("uint16", 1, "rw")
    assert got[("hr", "operating_time")][1:] == ("time_difference", 4, "ro")
    assert got[("hr", "counter")][1:] == ("uint64", 4, "rw")
    text = rm.to_markdown()
    assert "time_of_day (Unix ms as uint64, high word first)" in text
    assert "time_difference (ms as uint64, high word first)" in text


def test_an_object_of_a_tpdo_and_an_rpdo_gets_a_zenoh_value_key() -> None:
    keys = {k.key for k in all_keys(*with_nodes(cfg()))}
    assert "canopen/gateway/dev/value/command_number" in keys
    assert "canopen/gateway/dev/set/command_number" in keys
    assert "canopen/gateway/dev/value/command_argument" not in keys  # RPDO only


def test_as_float_on_a_time_type_is_a_config_error_naming_the_key() -> None:
    node = {**NODE, "signals": {"time_stamp": {"as_float": True}}}
    with pytest.raises(ConfigError) as exc:
        parse_checked_config({"nodes": [node]}, "c.yaml", environ={})
    assert exc.value.problems == [
        "c.yaml: nodes[0].signals.time_stamp.as_float: time_stamp is a time_of_day: "
        "as_float applies to numbers only"
    ]


# --------------------------------------------------------------------------- ASCII (CiA 309-3)
def test_an_untyped_ascii_read_of_a_real64_keeps_the_digits_of_a_double() -> None:
    assert format_plain(6.02214076e23) == "6.02214076e+23"
    assert format_plain(1e300) == "1e+300"  # beyond a single's range
    assert format_plain(struct.unpack("<f", struct.pack("<f", 0.1))[0]) == "0.1"  # a REAL32


def test_the_web_trends_draw_numbers_not_times_of_day() -> None:
    def meta(type_: str) -> SignalMeta:
        return SignalMeta(_sig(type_), IDENTITY, "TPDO", "", ())

    assert is_trend_signal(meta("float64")) and is_trend_signal(meta("int48"))
    assert is_trend_signal(meta("time_difference"))  # milliseconds
    assert not is_trend_signal(meta("time_of_day"))  # ISO 8601 text
