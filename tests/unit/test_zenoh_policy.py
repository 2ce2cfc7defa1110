"""Report by exception (deadband, max rate, quality changes) with a fake clock, and the JSON
payloads of the Zenoh bridge: engineering values both ways, and what a malformed request says."""

from __future__ import annotations

import json

import pytest

from canopen_gateway.errors import NodeNotOperational, SdoAbort
from canopen_gateway.image import EmcyRecord, NmtState, NodeImage, Quality, SignalValue
from canopen_gateway.northbound.scaling import Scaling, engineering, to_raw
from canopen_gateway.profiles.schema import Signal
from canopen_gateway.zenoh_bridge.payloads import (
    emcy_payload,
    error_payload,
    nmt_command,
    sdo_write_body,
    set_body,
    set_many_body,
    state_fingerprint,
    state_payload,
    value_payload,
)
from canopen_gateway.zenoh_bridge.policy import ReportPolicy

GOOD, STALE = Quality.GOOD, Quality.STALE


# --------------------------------------------------------------------------- policy


def test_first_sample_is_published_then_only_changes() -> None:
    p = ReportPolicy("change")
    assert p.offer(10, GOOD, 0.0)
    p.published(10, GOOD, 0.0)
    assert not p.offer(10, GOOD, 0.1)
    assert p.offer(11, GOOD, 0.2)


def test_publish_every_sends_unchanged_samples() -> None:
    p = ReportPolicy("every")
    p.published(10, GOOD, 0.0)
    assert p.offer(10, GOOD, 0.1)


def test_a_quality_change_is_published_even_with_the_same_value() -> None:
    p = ReportPolicy("change", deadband=5.0)
    p.published(10, GOOD, 0.0)
    assert p.offer(10, STALE, 0.1)


def test_deadband_is_in_engineering_units() -> None:
    # raw steps of 0.1 mm, deadband 0.5 mm: 4 steps stay quiet, 5 steps are published
    p = ReportPolicy("change", deadband=0.5, scale=0.1)
    p.published(100, GOOD, 0.0)
    assert not p.offer(104, GOOD, 0.1)
    assert not p.offer(96, GOOD, 0.1)
    assert p.offer(105, GOOD, 0.1)
    assert p.offer(95, GOOD, 0.1)


def test_deadband_is_measured_from_the_last_published_value_not_the_last_sample() -> None:
    p = ReportPolicy("change", deadband=1.0)
    p.published(0, GOOD, 0.0)
    for v in (0.4, 0.8):  # a slow drift, each step below the deadband
        assert not p.offer(v, GOOD, 0.1)
    assert p.offer(1.2, GOOD, 0.2)


def test_max_rate_holds_back_and_releases_the_latest_value_when_due() -> None:
    p = ReportPolicy("change", max_rate_hz=10)  # at most one sample per 100 ms
    p.published(1, GOOD, 0.0)
    assert not p.offer(2, GOOD, 0.05)
    assert p.pending
    assert not p.take_due(0.0999)
    assert p.take_due(0.1)
    assert not p.pending
    assert p.offer(3, GOOD, 0.1)  # the caller offers the current value again


def test_max_rate_edge_exactly_one_interval_later_is_allowed() -> None:
    p = ReportPolicy("every", max_rate_hz=4)
    p.published(1, GOOD, 1.0)
    assert not p.offer(1, GOOD, 1.2499)
    assert p.offer(1, GOOD, 1.25)


def test_nothing_is_due_without_a_held_back_sample() -> None:
    p = ReportPolicy("change", max_rate_hz=10)
    p.published(1, GOOD, 0.0)
    assert not p.take_due(5.0)


def test_policy_rejects_an_unknown_mode() -> None:
    with pytest.raises(ValueError, match="change or every"):
        ReportPolicy("sometimes")  # type: ignore[arg-type]


# --------------------------------------------------------------------------- payloads

POSITION = Signal(name="position", object="0x6020:01", type="int32", unit="mm", scale=0.1)
STATUS = Signal(
    name="status_word",
    object="0x5F19:00",
    type="uint16",
    bits=[{"bit": 8, "name": "guarding_bit"}, {"bit": 0, "width": 4, "name": "low_nibble"}],
)
TEXT = Signal(name="row", object="0x5F16:04", type="string", length=2)
MODE = Signal(name="mode", object="0x2005:00", type="uint8", values={1: "type1", 2: "type2"})


def test_engineering_value_is_raw_times_scale_plus_offset_without_float_noise() -> None:
    sc = Scaling("mm", 0.1, 0.0)
    assert engineering(POSITION, 12345, sc) == 1234.5
    assert engineering(POSITION, 3, Scaling("mm", 0.1, 100.0)) == 100.3
    assert engineering(POSITION, 7, Scaling("", 1.0, 0.0)) == 7
    assert engineering(TEXT, b"AB\0\0", Scaling("", 1.0, 0.0)) == "AB"


def test_written_engineering_values_round_to_the_nearest_raw_step() -> None:
    sc = Scaling("mm", 0.1, 0.0)
    assert to_raw(POSITION, 12.3, sc) == 123
    assert to_raw(POSITION, 12.34, sc) == 123
    assert to_raw(POSITION, 5, Scaling("mm", 1.0, 0.0)) == 5
    assert to_raw(POSITION, 1.5, Scaling("mm", 1.0, 0.0)) == 1.5  # left to the range check
    assert to_raw(POSITION, 100.3, Scaling("mm", 0.1, 100.0)) == 3
    with pytest.raises(ValueError, match="expected a number"):
        to_raw(POSITION, [1], sc)


def test_value_payload_has_value_unit_source_time_quality_seq_and_named_bits() -> None:
    sv = SignalValue("status_word", value=0x0105, timestamp=1700000000.5, seq=7)
    d = value_payload(STATUS, sv, Quality.GOOD, Scaling("", 1.0, 0.0))
    assert d == {
        "value": 0x0105,
        "unit": "",
        "ts": 1700000000.5,
        "quality": "good",
        "seq": 7,
        "bits": {"guarding_bit": True, "low_nibble": 5},
    }


def test_value_payload_names_an_enum_value_and_is_empty_before_the_first_frame() -> None:
    sc = Scaling("", 1.0, 0.0)
    d = value_payload(MODE, SignalValue("mode", value=2, timestamp=1.0, seq=1), Quality.GOOD, sc)
    assert d["text"] == "type2"
    never = value_payload(MODE, SignalValue("mode"), Quality.BAD, sc)
    assert never == {"value": None, "unit": "", "ts": None, "quality": "bad", "seq": 0}


def test_state_payload_and_its_fingerprint_ignore_time() -> None:
    node = NodeImage("wire", 1, "sgh10", ["position"])
    node.health.nmt_state = NmtState.OPERATIONAL
    node.health.alive = True
    a = state_payload(node, now_s=1.0)
    assert a["nmt_state"] == "operational" and a["operational"] is True and a["link"] == "not_used"
    assert state_fingerprint(a) == state_fingerprint(state_payload(node, now_s=2.0))
    node.health.alive = False
    assert state_fingerprint(a) != state_fingerprint(state_payload(node, now_s=3.0))
    json.dumps(a)


def test_emcy_payload_marks_an_error_reset() -> None:
    node = NodeImage("wire", 1, "sgh10", [])
    rec = EmcyRecord(0x0000, 0x00, b"\0" * 5, "Error reset or no error", 5.0)
    d = emcy_payload(node, rec, 3)
    assert d["code"] == "0x0000" and d["reset"] is True and d["count"] == 3
    assert d["manufacturer"] == "0000000000"


def test_error_payload_carries_the_sdo_abort_code_and_text() -> None:
    d = error_payload(SdoAbort(0x06090011, node="wire", obj="0x6000:07"), "k")
    assert d["error"] == "sdo_abort" and d["code"] == "0x06090011" and d["key"] == "k"
    assert d["text"] == "Sub-index does not exist"  # DS-301 abort code table
    assert (
        error_payload(NodeNotOperational("wire", "not alive"), "k")["error"]
        == "node_not_operational"
    )
    assert error_payload(ValueError("expected x"), "k") == {
        "error": "bad_request", "message": "expected x", "key": "k"
    }  # fmt: skip
    assert error_payload(RuntimeError("boom"), "k")["error"] == "internal"


@pytest.mark.parametrize(
    ("payload", "command"),
    [
        (b"start", "start"),
        (b'"stop"', "stop"),
        (b'{"command": "reset-comm"}', "reset-comm"),
        (b" preop\n", "preop"),
    ],
)
def test_nmt_command_accepts_text_json_string_or_object(payload: bytes, command: str) -> None:
    assert nmt_command(payload) == command


@pytest.mark.parametrize("payload", [None, b"", b"{}", b"[1]", b"\xff\xfe"])
def test_nmt_command_without_a_command_says_what_was_expected(payload: bytes | None) -> None:
    with pytest.raises(ValueError, match="start, stop, preop, reset or reset-comm"):
        nmt_command(payload)


def test_sdo_write_body_forms() -> None:
    assert sdo_write_body(b"5") == (5, None)
    assert sdo_write_body(b'"SGH10"') == ("SGH10", None)
    assert sdo_write_body(b'{"value": 7, "type": "uint16"}') == (7, "uint16")
    assert sdo_write_body(b'{"hex": "0a0B"}') == (b"\x0a\x0b", None)
    for bad, words in [
        (None, "payload missing"),
        (b"{oops", "not JSON"),
        (b'{"hex": "zz"}', "not hexadecimal"),
        (b'{"type": "uint8"}', "expected a JSON value"),
        (b'{"value": 1, "type": 3}', "type must be a name"),
        (b"[1]", "expected a JSON value"),
        (b"null", "expected a JSON value"),
    ]:
        with pytest.raises(ValueError, match=None) as exc:
            sdo_write_body(bad)
        assert words in str(exc.value), (bad, str(exc.value))


def test_set_body_forms() -> None:
    assert set_body(b"12.5").value == 12.5
    assert set_body(b'{"value": 3}').value == 3
    raw = set_body(b'{"raw": 30}')
    assert raw.raw and raw.value == 30
    assert set_body(b'{"bits": {"led_blinking": 1}}').bits == {"led_blinking": True}
    for bad in (b"{}", b'{"bits": []}', b"[1]", b"null", b"nope"):
        with pytest.raises(ValueError, match="expected|bits"):
            set_body(bad)


def test_set_many_body_needs_a_non_empty_object() -> None:
    assert set_many_body(b'{"a": 1}') == {"a": 1}
    for bad in (b"{}", b"1", b"[]"):
        with pytest.raises(ValueError, match='"signal": value'):
            set_many_body(bad)
