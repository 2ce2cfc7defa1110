"""EMCY decoding and history, with the frames and codes of the manuals' EMCY tables.

Profile texts are copied here as data (tests must not read the manuals): SGH10 manual 4.5.1
table 9, AP05 manual 5.5.1 table 31.
"""

from __future__ import annotations

import pytest

from canopen_gateway.bus.emcy import EmcyHistory, ErrorRaised, ErrorsCleared
from canopen_gateway.canopen.emcy import (
    Emcy,
    decode_emcy,
    emcy_text,
    generic_text,
    register_bits,
)

SGH10_TEXTS = {
    0x0000: "Cause of the error removed",
    0x8120: "Bus status changed over to the error passive mode",
    0x8140: "Recovered from Bus Off",
    0xFF05: "Position value error",
    0xFF15: "Position error work area 1",
    0xFF16: "Position error work area 2",
}


class TestDecode:
    def test_code_is_little_endian_then_register_then_manufacturer_bytes(self) -> None:
        e = decode_emcy(bytes([0x05, 0xFF, 0x81, 1, 2, 3, 4, 5]), SGH10_TEXTS, timestamp=7.5)
        assert e.code == 0xFF05
        assert e.register == 0x81
        assert e.manufacturer == bytes([1, 2, 3, 4, 5])
        assert e.text == "Position value error"
        assert e.timestamp == 7.5

    def test_profile_text_wins_over_generic_text(self) -> None:
        e = decode_emcy(bytes([0x20, 0x81, 0x11, 0, 0, 0, 0, 0]), SGH10_TEXTS)
        assert e.text == "Bus status changed over to the error passive mode"
        assert e.generic == "CAN in error passive mode"

    def test_without_profile_text_the_ds301_text_is_used(self) -> None:
        e = decode_emcy(bytes([0x30, 0x81, 0x11, 0, 0, 0, 0, 0]), SGH10_TEXTS)
        assert e.text == "Life guard error or heartbeat error"

    def test_short_frame_with_code_and_register_decodes(self) -> None:
        e = decode_emcy(bytes([0x00, 0x32, 0x04]))
        assert (e.code, e.register, e.manufacturer) == (0x3200, 0x04, b"")

    def test_frame_shorter_than_three_bytes_is_rejected(self) -> None:
        with pytest.raises(ValueError, match="at least 3"):
            decode_emcy(bytes([0x05, 0xFF]))

    def test_reset_code_is_recognised(self) -> None:
        assert decode_emcy(bytes(8)).is_reset

    def test_str_names_code_text_and_register_bits(self) -> None:
        e = decode_emcy(bytes([0x05, 0xFF, 0x81, 0, 0, 0, 0, 0]), SGH10_TEXTS)
        assert str(e) == (
            "EMCY 0xFF05 (Position value error), error register 0x81 "
            "[generic, manufacturer specific], manufacturer 00 00 00 00 00"
        )


class TestGenericTexts:
    @pytest.mark.parametrize(
        ("code", "text"),
        [
            (0x0000, "Error reset or no error"),
            (0x1000, "Generic error"),
            (0x2310, "Current, device output side"),
            (0x2000, "Current"),
            (0x3200, "Voltage inside the device"),  # AP05 "battery empty"
            (0x4210, "Device temperature"),
            (0x5530, "Device hardware"),
            (0x6100, "Internal software"),
            (0x7000, "Additional modules"),
            (0x8110, "CAN overrun (objects lost)"),
            (0x8120, "CAN in error passive mode"),
            (0x8130, "Life guard error or heartbeat error"),
            (0x8140, "Recovered from bus off"),
            (0x8210, "PDO not processed due to length error"),
            (0x8299, "Protocol error"),
            (0x8F00, "Monitoring"),
            (0x9000, "External error"),
            (0xF001, "Additional functions"),
            (0xFF12, "Device specific"),
        ],
    )
    def test_ds301_class_texts(self, code: int, text: str) -> None:
        assert generic_text(code) == text

    def test_code_of_undefined_class_says_so(self) -> None:
        assert "does not define" in generic_text(0xA123)

    def test_emcy_text_falls_back_when_profile_has_no_entry(self) -> None:
        assert emcy_text(0xFF20, {0xFF12: "Speed error"}) == "Device specific"
        assert emcy_text(0xFF12, {0xFF12: "Speed error"}) == "Speed error"
        assert emcy_text(0xFF12, None) == "Device specific"

    def test_register_bit_names(self) -> None:
        assert register_bits(0x00) == []
        assert register_bits(0x11) == ["generic", "communication"]
        assert register_bits(0xFF)[-1] == "manufacturer specific"


def emcy(code: int, register: int = 0x01) -> Emcy:
    return decode_emcy(bytes([code & 0xFF, code >> 8, register, 0, 0, 0, 0, 0]), SGH10_TEXTS)


class TestHistory:
    def test_new_error_becomes_current_and_is_reported(self) -> None:
        h = EmcyHistory()
        out = h.add(emcy(0xFF15))
        assert out == [ErrorRaised(emcy(0xFF15))]
        assert set(h.current) == {0xFF15}
        assert h.count == 1 and h.last == emcy(0xFF15)

    def test_repeated_error_is_counted_but_not_reported_again(self) -> None:
        h = EmcyHistory()
        h.add(emcy(0xFF15))
        assert h.add(emcy(0xFF15)) == []
        assert h.count == 2 and len(h.history) == 2

    def test_several_errors_are_current_together(self) -> None:
        h = EmcyHistory()
        h.add(emcy(0xFF15))
        h.add(emcy(0xFF16))
        assert sorted(h.current) == [0xFF15, 0xFF16]

    def test_code_0000_clears_current_errors_and_keeps_the_register(self) -> None:
        h = EmcyHistory()
        h.add(emcy(0xFF15))
        h.add(emcy(0xFF16))
        out = h.add(emcy(0x0000, register=0x80))
        assert out == [ErrorsCleared((0xFF15, 0xFF16), 0x80)]
        assert h.current == {}
        assert h.register == 0x80  # something persists (SGH10 manual 4.5.1)
        assert h.count == 3

    def test_history_is_bounded_and_keeps_the_newest(self) -> None:
        h = EmcyHistory(max_history=3)
        for code in (0xFF05, 0xFF15, 0xFF16, 0x8120):
            h.add(emcy(code))
        assert [e.code for e in h.history] == [0xFF15, 0xFF16, 0x8120]
        assert h.count == 4

    def test_clear_forgets_current_errors_only(self) -> None:
        h = EmcyHistory()
        h.add(emcy(0xFF05))
        h.clear()
        assert h.current == {} and h.count == 1 and len(h.history) == 1
