"""Trace files of python-can's writers (``.asc``, ``.blf``, ``.trc``, ``.log``, ``.csv``) for
the frames the gateway hears: the one place a recording is written, for the ``monitor
--record`` command and the console's download.

python-can's writers read a frame's ``channel`` as a number (``can.util.channel2int``): the
digits at the end of a channel's name (``can1`` -> 1, a virtual bus named ``line-70000`` ->
70000). BLF stores it in 16 bits and fails on a larger one; ``trace_writer`` hands such a frame
on without its channel, so the writer numbers it with its own default, and leaves every other
frame as heard. A ``.trc`` file cannot hold remote frames (python-can's TRC writer): they are
counted and said (``TraceWriter.note``), not written.

Imports: python-can and the standard library only.
"""

from __future__ import annotations

import can
from can.util import channel2int

#: the trace formats a recording is written in (python-can's writers), by suffix
RECORD_FORMATS = (".asc", ".blf", ".trc", ".log", ".csv")

#: the largest channel number every writer stores (BLF: an unsigned 16-bit field)
_MAX_CHANNEL = 0xFFFE


def _writable(msg: can.Message) -> can.Message:
    if msg.channel is None:
        return msg
    number = channel2int(msg.channel)
    if number is None or 0 <= number <= _MAX_CHANNEL:
        return msg
    return can.Message(
        timestamp=msg.timestamp,
        arbitration_id=msg.arbitration_id,
        is_extended_id=msg.is_extended_id,
        is_remote_frame=msg.is_remote_frame,
        is_error_frame=msg.is_error_frame,
        dlc=msg.dlc,
        data=msg.data,
        is_fd=msg.is_fd,
        is_rx=msg.is_rx,
        bitrate_switch=msg.bitrate_switch,
        error_state_indicator=msg.error_state_indicator,
    )


#: formats whose python-can writer cannot hold a remote frame (RTR: node guarding's request):
#: such a frame is counted (``TraceWriter.left_out``), never handed on (the writer would log a
#: warning line per frame and write nothing)
NO_REMOTE_FRAMES = (".trc",)


class TraceWriter(can.Listener):
    """python-can's writer of ``path``'s format (its suffix), fed any frame the gateway has."""

    def __init__(self, path: str) -> None:
        self._writer = can.Logger(path)
        self._remote = not path.lower().endswith(NO_REMOTE_FRAMES)
        #: remote frames the format cannot hold, left out of the file
        self.left_out = 0

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_remote_frame and not self._remote:
            self.left_out += 1
            return
        self._writer.on_message_received(_writable(msg))

    def note(self) -> str | None:
        """What the file lacks, in a line (None: every frame is in it)."""
        if not self.left_out:
            return None
        return (f"{self.left_out} remote frame(s) (RTR, e.g. node guarding) not recorded: a .trc "
                "file of python-can's writer cannot hold them; .asc, .blf, .log and .csv do")  # fmt: skip

    def stop(self) -> None:
        self._writer.stop()


def trace_writer(path: str) -> TraceWriter:
    """The writer of ``path``'s format; ValueError naming the formats for another suffix."""
    suffix = path.rsplit(".", 1)[-1].lower() if "." in path else ""
    if f".{suffix}" not in RECORD_FORMATS:
        raise ValueError(f"--record {path}: the file's suffix says the format: {', '.join(RECORD_FORMATS)}")
    return TraceWriter(path)
