"""The CiA 309-3 ASCII mapping without I/O: every data type's text round trip, the grammar, the
session's defaults and write gate, every internal error code an answer can carry, the lines of
a TCP stream (CR LF, overlong lines) and the event lines from health samples."""

from __future__ import annotations

import struct

import pytest

from canopen_gateway.ascii.grammar import Iec, LineSplitter, Overlong, RequestError, tokenize
from canopen_gateway.ascii.protocol import (
    EventTracker,
    HealthSample,
    NmtCommand,
    SdoDownload,
    SdoUpload,
    Session,
    answer_for_error,
    parse_request,
)
from canopen_gateway.ascii.values import (
    DATA_TYPES,
    LengthMismatch,
    encode_value,
    format_plain,
    format_value,
)
from canopen_gateway.errors import (
    BusDown,
    Forbidden,
    NodeNotOperational,
    NodeUnknown,
    SdoAbort,
    SdoTimeout,
    ValueOutOfRange,
)

T = DATA_TYPES


# --------------------------------------------------------------------------- data types
@pytest.mark.parametrize(
    ("name", "text", "data"),
    [
        ("b", "1", b"\x01"),
        ("b", "0", b"\x00"),
        ("i8", "-128", b"\x80"),
        ("i16", "-2", b"\xfe\xff"),
        ("i32", "-100000", struct.pack("<i", -100000)),
        ("i64", "-9223372036854775808", struct.pack("<q", -(2**63))),
        ("u8", "255", b"\xff"),
        ("u16", "65535", b"\xff\xff"),
        ("u32", "4294967295", b"\xff\xff\xff\xff"),
        ("u64", "18446744073709551615", b"\xff" * 8),
        ("x8", "0x0A", b"\x0a"),
        ("x16", "0x1234", b"\x34\x12"),
        ("x32", "0x00000192", b"\x92\x01\x00\x00"),
        ("x64", "0x0123456789ABCDEF", bytes.fromhex("efcdab8967452301")),
        ("r32", "0.1", struct.pack("<f", 0.1)),
        ("r32", "-1.5", struct.pack("<f", -1.5)),
        ("r64", "3.141592653589793", struct.pack("<d", 3.141592653589793)),
        ("vs", "SGH10", b"SGH10"),
        ("vs", '"two words"', b"two words"),
        ("vs", '"say ""hi"""', b'say "hi"'),
        ("os", "AQID", b"\x01\x02\x03"),
        ("d", "aGVsbG8gd29ybGQ=", b"hello world"),
    ],
)
def test_every_data_type_round_trips_between_text_and_bytes(name: str, text: str, data: bytes) -> None:
    dtype = T[name]
    (token,) = tokenize(text)
    assert encode_value(dtype, token) == data
    assert format_value(dtype, data) == text


def test_integers_are_read_in_decimal_or_hex_whatever_the_type() -> None:
    assert encode_value(T["u16"], "0x10") == b"\x10\x00"
    assert encode_value(T["x16"], "16") == b"\x10\x00"
    assert encode_value(T["u8"], "007") == b"\x07"


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("u8", "256"), ("i8", "128"), ("u32", "-1"), ("b", "2"), ("u16", "ten"),
        ("r32", "1e39"), ("r64", "x"), ("vs", ""), ("vs", "caf\u00e9"), ("os", "!!"),
        ("d", ""), ("u64", "0x1G"),
    ],
)  # fmt: skip
def test_a_value_that_is_not_of_its_type_is_refused(name: str, text: str) -> None:
    with pytest.raises(ValueError):
        encode_value(T[name], text)


def test_an_expedited_upload_without_size_is_cut_to_the_type_but_real_extra_bytes_are_not() -> None:
    assert format_value(T["u8"], b"\x07\x00\x00\x00") == "7"
    with pytest.raises(LengthMismatch):
        format_value(T["u8"], b"\x07\x01")
    with pytest.raises(LengthMismatch):
        format_value(T["u32"], b"\x07\x00")


def test_a_visible_string_is_shown_without_its_padding_and_quoted_only_when_needed() -> None:
    assert format_value(T["vs"], b"AP05\x00\x00") == "AP05"
    assert format_value(T["vs"], b"") == '""'
    assert format_value(T["vs"], b"#1") == '"#1"'


def test_values_read_without_a_type_are_shown_by_their_python_type() -> None:
    assert format_plain(0x192) == "402"
    assert format_plain(True) == "1"
    assert format_plain(0.25) == "0.25"
    assert format_plain("SIKO GmbH") == '"SIKO GmbH"'
    assert format_plain(b"\x01\x02") == "AQI="


# --------------------------------------------------------------------------- grammar
def test_tokens_split_on_blanks_quotes_keep_blanks_and_a_hash_starts_a_comment() -> None:
    assert tokenize('[1] 5 w 0x2000 0 vs "a b" # set the text') == [
        "[1]", "5", "w", "0x2000", "0", "vs", "a b"
    ]  # fmt: skip
    assert tokenize("\t# only a comment") == []
    with pytest.raises(ValueError):
        tokenize('w 1 2 vs "open')
    with pytest.raises(ValueError):
        tokenize('w 1 2 vs "a"b')


def test_prefix_numbers_are_node_or_net_and_node() -> None:
    r = parse_request("[7] 1 5 read 0x1018 0x01 u32")
    assert (r.seq, r.net, r.node, r.index, r.sub, r.dtype.name) == (7, 1, 5, 0x1018, 1, "u32")
    r = parse_request("[0] 5 r 4120 1")
    assert (r.seq, r.net, r.node, r.dtype) == (0, None, 5, None)
    r = parse_request("[1] 1 set node 5")  # one number before a network-level command: the net
    assert (r.net, r.value) == (1, 5)


def test_commands_are_case_insensitive_and_long_forms_work() -> None:
    assert parse_request("[1] 5 PREOPERATIONAL").command == "preop"
    assert parse_request("[1] 5 Reset Communication").command == "reset-comm"
    assert parse_request("[1] 5 reset comm").command == "reset-comm"
    assert parse_request("[1] 5 reset node").command == "reset"
    assert parse_request("[1] 5 WRITE 0x1017 0 U16 100").data == b"\x64\x00"


@pytest.mark.parametrize(
    ("line", "code"),
    [
        ("[1] 5 r 0x1018", Iec.SYNTAX),  # sub-index missing
        ("[1] 5 r 0x10000 0", Iec.SYNTAX),  # index out of range
        ("[1] 5 r 0x1018 256", Iec.SYNTAX),
        ("[1] 5 r 0x1018 1 u33", Iec.SYNTAX),  # unknown data type
        ("[1] 5 r 0x1018 1 t", Iec.REQUEST_NOT_SUPPORTED),  # TIME_OF_DAY: not offered
        ("[1] 5 w 0x1017 0 u16", Iec.SYNTAX),  # value missing
        ("[1] 5 w 0x1017 0 u16 70000", Iec.SYNTAX),
        ("[1] 5 w 0x1017 0 u16 1 2", Iec.SYNTAX),
        ("[1] 1 2 3 r 1 1", Iec.SYNTAX),
        ("[1] 5 start now", Iec.SYNTAX),
        ("[1] 5 reset everything", Iec.SYNTAX),
        ("[1] set node 128", Iec.SYNTAX),
        ("[1] set sdo_timeout 0", Iec.SYNTAX),
        ("[1] 5 set network 1", Iec.SYNTAX),
        ("[1] set sdo_block 1", Iec.REQUEST_NOT_SUPPORTED),
        ("[1] lss_store", Iec.REQUEST_NOT_SUPPORTED),
        ("[1] frobnicate", Iec.REQUEST_NOT_SUPPORTED),
        ("[1] info", Iec.REQUEST_NOT_SUPPORTED),
        ("[1] 5", Iec.SYNTAX),
        ("[1] 5 r 1 1 \x00\x01", Iec.SYNTAX),
    ],
)
def test_malformed_requests_get_their_error_code_with_their_sequence(line: str, code: Iec) -> None:
    with pytest.raises(RequestError) as err:
        parse_request(line)
    assert (err.value.seq, err.value.code) == (1, code)


@pytest.mark.parametrize("line", ["[x] r 1 1", "5 r 1 1", "[4294967296] info version", "[1]r 1 1", "hello"])
def test_a_missing_or_bad_sequence_is_a_syntax_error_without_sequence(line: str) -> None:
    with pytest.raises(RequestError) as err:
        parse_request(line)
    assert (err.value.seq, err.value.code) == (None, Iec.SYNTAX)


# --------------------------------------------------------------------------- session
def session(writes: bool = True) -> Session:
    return Session({1, 5}, writes=writes, version="1.2.3")


def test_a_read_resolves_to_an_sdo_upload_of_the_addressed_node() -> None:
    s = session()
    assert s.handle("[3] 5 r 0x1018 1 u32") == SdoUpload(3, 5, 0x1018, 1, T["u32"], None)


def test_the_default_node_and_the_sdo_timeout_are_the_sessions() -> None:
    s = session()
    assert s.handle("[1] r 0x1018 1") == ["[1] ERROR:105"]
    assert s.handle("[2] set node 5") == ["[2] OK"]
    assert s.handle("[3] set sdo_timeout 250") == ["[3] OK"]
    assert s.handle("[4] r 0x1018 1") == SdoUpload(4, 5, 0x1018, 1, None, 250)
    assert s.handle("[5] 1 r 0x1018 1") == SdoUpload(5, 1, 0x1018, 1, None, 250)
    other = session()
    assert other.handle("[1] r 0x1018 1") == ["[1] ERROR:105"]


def test_nets_and_nodes_the_gateway_does_not_have_are_refused() -> None:
    s = session()
    assert s.handle("[1] 2 5 r 0x1018 1") == ["[1] ERROR:106"]
    assert s.handle("[2] set network 2") == ["[2] ERROR:106"]
    assert s.handle("[3] set network 1") == ["[3] OK"]
    assert s.handle("[4] 2 set node 5") == ["[4] ERROR:106"]
    assert s.handle("[5] 9 r 0x1018 1") == ["[5] ERROR:107"]  # node 9 is not configured
    assert s.handle("[6] 200 r 0x1018 1") == ["[6] ERROR:107"]
    assert s.handle("[7] set node 9") == ["[7] ERROR:107"]
    assert s.handle("[8] 0 r 0x1018 1") == ["[8] ERROR:107"]  # node 0 is no SDO server


def test_without_a_default_net_a_request_without_net_gets_104() -> None:
    s = session()
    s.default_net = None
    assert s.handle("[1] 5 r 0x1018 1") == ["[1] ERROR:104"]
    assert s.handle("[2] 1 5 r 0x1018 1") == SdoUpload(2, 5, 0x1018, 1, None, None)


def test_writes_and_nmt_pass_the_write_gate_only_when_writes_are_on() -> None:
    off = session(writes=False)
    assert off.handle("[1] 5 w 0x1017 0 u16 100") == ["[1] ERROR:100"]
    assert off.handle("[2] 5 start") == ["[2] ERROR:100"]
    assert off.handle("[3] 5 reset node") == ["[3] ERROR:100"]
    assert isinstance(off.handle("[4] 5 r 0x1017 0 u16"), SdoUpload)
    on = session(writes=True)
    assert on.handle("[1] 5 w 0x1017 0 u16 100") == SdoDownload(1, 5, 0x1017, 0, b"\x64\x00", None)
    assert on.handle("[2] 5 stop") == NmtCommand(2, 5, "stop")
    assert on.handle("[3] 0 start") == NmtCommand(3, 0, "start")  # node 0: every node


def test_help_is_comment_lines_then_ok_and_info_version_names_the_protocol() -> None:
    s = session()
    lines = s.handle("[9] help")
    assert isinstance(lines, list) and lines[-1] == "[9] OK"
    assert all(line.startswith("# ") for line in lines[:-1]) and len(lines) > 5
    assert s.handle("[10] help datatype")[-1] == "[10] OK"
    assert s.handle("[11] help lss") == ["[11] ERROR:100"]
    assert s.handle("[12] info version") == ["[12] 0 0 1.2 0 3 3.0 1.2"]


def test_an_empty_or_comment_line_gets_no_answer_and_a_line_without_sequence_101() -> None:
    s = session()
    assert s.handle("") == []
    assert s.handle("   # nothing") == []
    assert s.handle("set node 5") == ["ERROR:101"]
    assert s.default_node is None
    assert s.handle("garbage") == ["ERROR:101"]
    assert s.handle("[1] garbage") == ["[1] ERROR:100"]  # an unknown command


def test_an_overlong_line_is_a_syntax_error_with_the_sequence_it_started_with() -> None:
    s = session()
    assert s.handle(Overlong(42)) == ["[42] ERROR:101"]
    assert s.handle(Overlong(None)) == ["ERROR:101"]


@pytest.mark.parametrize(
    ("exc", "answer"),
    [
        (SdoAbort(0x06020000), "[4] ERROR:0x06020000"),
        (SdoTimeout("n", "0x1018:01"), "[4] ERROR:0x05040000"),
        (TimeoutError(), "[4] ERROR:0x05040000"),
        (LengthMismatch("2 bytes"), "[4] ERROR:0x06070010"),
        (NodeUnknown("x"), "[4] ERROR:107"),
        (NodeNotOperational("n", "not alive"), "[4] ERROR:102"),
        (BusDown(), "[4] ERROR:102"),
        (Forbidden("no"), "[4] ERROR:100"),
        (ValueOutOfRange("x", 1, "2"), "[4] ERROR:101"),
        (RuntimeError("bug"), "[4] ERROR:102"),
    ],
)
def test_command_service_errors_become_abort_codes_or_internal_codes(exc: BaseException, answer: str) -> None:
    assert answer_for_error(4, exc) == answer


# --------------------------------------------------------------------------- lines
def test_lines_end_with_cr_lf_or_lf_and_may_arrive_in_pieces() -> None:
    sp = LineSplitter()
    assert sp.feed(b"[1] 5 r 0x1018 1\r") == []
    assert sp.feed(b"\n[2] help\n[3] in") == ["[1] 5 r 0x1018 1", "[2] help"]
    assert sp.feed(b"fo version\r\n") == ["[3] info version"]


def test_a_line_over_1_kib_is_reported_once_and_skipped_up_to_its_end() -> None:
    sp = LineSplitter()
    out = sp.feed(b"[5] w 0x2000 0 vs " + b"A" * 2000)
    assert out == [Overlong(5)]
    assert sp.feed(b"B" * 5000) == []
    assert sp.feed(b"C\r\n[6] info version\r\n") == ["[6] info version"]
    exact = b"x" * 1024
    assert sp.feed(exact + b"\r\n" + b"y" * 1025 + b"\n") == [exact.decode(), Overlong(None)]


def test_bytes_that_are_not_ascii_make_a_syntax_error_not_a_crash() -> None:
    sp = LineSplitter()
    (line,) = sp.feed(b"[8] \xff\xfe r 1 1\n")
    assert session().handle(line) == ["[8] ERROR:101"]


# --------------------------------------------------------------------------- events
def hs(
    alive: bool, boots: int = 1, emcys: int = 0, sup: str = "heartbeat", losses: int = 0
) -> HealthSample:
    return HealthSample(alive, boots, emcys, sup, losses)


def test_events_boot_up_emcy_heartbeat_lost_and_started() -> None:
    t = EventTracker()
    assert t.update(5, hs(False, boots=0)) == []  # the first sample is the reference
    assert t.update(5, hs(True, boots=1)) == ["1 5 BOOT_UP"]
    emcy = (0x8130, 0x11, bytes([1, 2, 3, 4, 5]))
    assert t.update(5, hs(True, emcys=1), emcy) == ["1 5 EMCY 8130 11 1 2 3 4 5"]
    assert t.update(5, hs(False, losses=1)) == ["1 5 ERROR 203 (Heartbeat lost)"]
    assert t.update(5, hs(True, losses=1)) == ["1 5 ERROR 202 (Heartbeat started)"]
    assert t.update(5, hs(True, losses=1)) == []


def test_a_loss_and_its_end_in_one_health_change_give_both_lines() -> None:
    t = EventTracker()
    t.update(5, hs(True))
    assert t.update(5, hs(True, losses=1)) == [
        "1 5 ERROR 203 (Heartbeat lost)", "1 5 ERROR 202 (Heartbeat started)"
    ]  # fmt: skip


def test_a_guarded_node_lost_is_error_200_and_unsupervised_nodes_give_no_loss_event() -> None:
    t = EventTracker()
    t.update(3, hs(True, sup="guarding"))
    assert t.update(3, hs(False, sup="guarding", losses=1)) == [
        "1 3 ERROR 200 (Lost guarding message)"
    ]
    assert t.update(3, hs(True, sup="guarding", losses=1)) == []
    t.update(4, hs(True, sup="none"))
    assert t.update(4, hs(False, sup="none", losses=1)) == []


def test_a_node_that_reboots_after_a_loss_says_boot_up_not_heartbeat_started() -> None:
    t = EventTracker()
    t.update(5, hs(False, boots=1, losses=1))
    assert t.update(5, hs(True, boots=2, losses=1)) == ["1 5 BOOT_UP"]
