"""The SDO client machine (canopen_gateway.bus.sdo.client) byte for byte against the manuals' worked
examples (SGH10 manual 4.4.1.4), with a fake clock for timeouts and retries."""

from __future__ import annotations

import math

import pytest

from canopen_gateway.bus.sdo.client import ABORT_TIMEOUT, ABORT_TOGGLE, SdoTransfer


def h(text: str) -> bytes:
    return bytes.fromhex(text.replace(" ", ""))


def test_expedited_upload_of_the_calibration_value_as_in_4_4_1_4() -> None:
    t = SdoTransfer(0x6010, 1)
    assert t.start(0.0) == [h("40 10 60 01 00 00 00 00")]
    assert t.on_response(h("43 10 60 01 FE 01 00 00"), 0.01) == []
    assert t.done and t.result == h("FE 01 00 00")


def test_expedited_download_of_6200h_as_in_4_4_1_4() -> None:
    t = SdoTransfer(0x6200, 0, (4500).to_bytes(2, "little"))
    assert t.start(0.0) == [h("2B 00 62 00 94 11 00 00")]
    t.on_response(h("60 00 62 00 00 00 00 00"), 0.01)
    assert t.done and t.result == b""


def test_segmented_upload_of_1008h_sgh10_as_in_4_4_1_4() -> None:
    t = SdoTransfer(0x1008, 0)
    assert t.start(0.0) == [h("40 08 10 00 00 00 00 00")]
    assert t.on_response(h("41 08 10 00 05 00 00 00"), 0.01) == [h("60 00 00 00 00 00 00 00")]
    assert t.on_response(h("03 53 47 48 31 30 00 00"), 0.02) == []
    assert t.done and t.result == b"SGH10"


def test_segmented_upload_alternates_the_toggle_and_refuses_a_repeated_one() -> None:
    t = SdoTransfer(0x1008, 0)
    t.start(0.0)
    t.on_response(h("41 08 10 00 0A 00 00 00"), 0.0)
    assert t.on_response(h("00 4D 53 4B 35 30 30 30"), 0.0) == [h("70 00 00 00 00 00 00 00")]
    # the server repeats toggle 0: abort 05030000h naming 1008h:00
    assert t.on_response(h("00 43 41 4E 00 00 00 00"), 0.0) == [h("80 08 10 00 00 00 03 05")]
    assert t.done and t.abort_code == ABORT_TOGGLE and not t.aborted_by_server


def test_segmented_download_sends_seven_bytes_per_segment_with_the_last_flagged() -> None:
    t = SdoTransfer(0x1008, 0, b"ABCDEFGHIJ")
    assert t.start(0.0) == [h("21 08 10 00 0A 00 00 00")]
    assert t.on_response(h("60 08 10 00 00 00 00 00"), 0.0) == [h("00 41 42 43 44 45 46 47")]
    # 3 bytes left: n = 4 unused, c = 1, toggle 1
    assert t.on_response(h("20 00 00 00 00 00 00 00"), 0.0) == [h("19 48 49 4A 00 00 00 00")]
    assert t.on_response(h("30 00 00 00 00 00 00 00"), 0.0) == []
    assert t.done and t.result == b""


def test_a_server_abort_ends_the_transfer_with_its_code() -> None:
    t = SdoTransfer(0x1018, 7)
    t.start(0.0)
    assert t.on_response(h("80 18 10 07 11 00 09 06"), 0.0) == []
    assert t.done and t.abort_code == 0x06090011 and t.aborted_by_server


def test_an_unanswered_request_is_repeated_then_aborted_naming_the_object() -> None:
    t = SdoTransfer(0x1018, 1, timeout_s=0.5, retries=2)
    req = t.start(10.0)[0]
    assert t.next_deadline() == 10.5
    assert t.poll(10.5) == []  # not yet: a timeout expires strictly after its deadline
    assert t.poll(math.nextafter(10.5, 11)) == [req]
    assert t.poll(11.1) == [req]
    assert t.poll(11.7) == [h("80 18 10 01 00 00 04 05")]
    assert t.done and t.timed_out and t.abort_code == ABORT_TIMEOUT


def test_an_answer_for_another_object_is_not_taken() -> None:
    t = SdoTransfer(0x1018, 1)
    t.start(0.0)
    assert t.on_response(h("43 00 10 00 96 01 08 00"), 0.0) == []
    assert not t.done


def test_cancel_without_an_abort_frame_after_a_reboot() -> None:
    t = SdoTransfer(0x1000, 0)
    t.start(0.0)
    assert t.cancel(send_abort=False) == []
    assert t.done and t.result is None


class TestTheTableIsData:
    """``RESPONSES`` and ``PHASE_CHANGES`` are what the transfer reads (h11 ``_state.py``
    style): a server's wrong answer is aborted and counted, our own wrong move raises."""

    def test_an_answer_with_another_command_specifier_is_aborted_and_counted(self) -> None:
        from canopen_gateway.bus.sdo.client import SdoPhase, SdoTransfer

        t = SdoTransfer(0x1017, 0x00)
        t.start(0.0)
        # a download answer (60h) to an upload request: CiA 301 abort 0504 0001h
        frames = t.on_response(bytes([0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0]), 0.1)
        assert frames == [bytes([0x80, 0x17, 0x10, 0x00, 0x01, 0x00, 0x04, 0x05])]
        assert t.phase is SdoPhase.DONE and t.abort_code == 0x05040001
        assert t.protocol_errors == 1

    def test_a_phase_change_the_table_does_not_define_raises(self) -> None:
        from canopen_gateway.bus.sdo.client import (
            PHASE_CHANGES,
            SdoPhase,
            SdoStateError,
            SdoTransfer,
        )

        t = SdoTransfer(0x1017, 0x00)
        assert (SdoPhase.IDLE, SdoPhase.UP_SEG) not in PHASE_CHANGES
        with pytest.raises(SdoStateError, match="no phase change from idle to upload-segment"):
            t._enter(SdoPhase.UP_SEG)
        assert t.phase is SdoPhase.IDLE
