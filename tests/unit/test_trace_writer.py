"""A recording is written whatever the bus's channel is called: python-can's writers read the
digits at the end of a channel's name as its number (BLF keeps 16 bits of it)."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from canopen_gateway.bus.trace import RECORD_FORMATS, trace_writer


@pytest.mark.parametrize("suffix", RECORD_FORMATS)
@pytest.mark.parametrize("channel", ["line-70000", "can1", None])
def test_a_frame_of_any_channel_name_is_written_and_read_back(
    tmp_path: Path, suffix: str, channel: str | None
) -> None:
    path = tmp_path / f"trace{suffix}"
    writer = trace_writer(str(path))
    sent = can.Message(
        timestamp=1.5, arbitration_id=0x181, is_extended_id=False, data=b"\x01\x02", channel=channel
    )
    writer.on_message_received(sent)
    writer.stop()
    read = list(can.LogReader(str(path)))
    assert [(m.arbitration_id, bytes(m.data)) for m in read] == [(0x181, b"\x01\x02")]


def test_a_file_of_another_suffix_is_refused_naming_the_formats(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"\.asc, \.blf"):
        trace_writer(str(tmp_path / "trace.txt"))
