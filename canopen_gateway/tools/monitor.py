"""``canopen-gateway monitor``: candump for CANopen, one decoded line per frame; with
``--record FILE`` every frame also goes to a python-can writer (``can.Logger``: the format is
FILE's: .asc Vector ASCII, .blf Vector binary, .trc PCAN-View, .log candump, .csv); and
``canopen-gateway decode FILE``: the frames of a trace any python-can reader reads
(``can.LogReader``), one decoded line each.

Reads frames from a python-can bus and prints them as ``canopen_gateway.northbound.frames`` words them,
filtered by node (name or id) and kind (nmt, sync, time, emcy, pdo, sdo, heartbeat, lss,
other: the printed lines only, the recording keeps every frame); stops after ``count`` lines or
``duration_s`` seconds, or at Ctrl-C.

Line: seconds since the start (of the trace), COB-ID, node, service, text:
``   0.104  181  wire         TPDO1         position=1234.5 mm velocity=0 mm/s``

Imports: python-can, config, northbound.frames.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

import can

from canopen_gateway.northbound.frames import Decoded, FrameDecoder


def format_line(t: float, cob_id: int, d: Decoded) -> str:
    who = d.node or (f"id {d.node_id}" if d.node_id is not None else "-")
    return f"{t:8.3f}  {cob_id:03X}  {who:<12} {d.service:<13} {d.text}".rstrip()


def decoded(decoder: FrameDecoder, msg: can.Message) -> Decoded:
    """A frame in words; an error frame and a 29-bit frame (not CANopen) say so."""
    data = bytes(msg.data)
    if msg.is_error_frame:
        return Decoded("other", None, None, "error frame", f"CAN error frame {data.hex(' ')}".rstrip())
    if msg.is_extended_id:
        return Decoded("other", None, None, "29-bit", f"id {msg.arbitration_id:08X}, not CANopen: {data.hex(' ')}".rstrip())  # fmt: skip
    return decoder.decode(msg.arbitration_id, data, msg.is_remote_frame)


def decode_file(path: str, decoder: FrameDecoder, out: TextIO) -> int:
    """One line per frame of a trace python-can reads (``can.LogReader``: .asc, .blf, .trc,
    .log, .csv, .db, .mf4); the time from the trace's first frame. Returns the frames."""
    start: float | None = None
    n = 0
    with can.LogReader(path) as reader:
        for msg in reader:
            if start is None:
                start = msg.timestamp
            out.write(format_line(msg.timestamp - start, msg.arbitration_id, decoded(decoder, msg)) + "\n")
            n += 1
    return n


def monitor(
    bus: can.BusABC,
    decoder: FrameDecoder,
    out: TextIO,
    *,
    nodes: set[int] | None = None,
    kinds: set[str] | None = None,
    count: int | None = None,
    duration_s: float | None = None,
    clock: Callable[[], float] = time.monotonic,
    record: can.Listener | None = None,
) -> int:
    """Print decoded frames until ``count`` lines or ``duration_s``; returns the lines printed.
    ``record``: a writer given every frame received (the caller stops it)."""
    start = clock()
    printed = 0
    while count is None or printed < count:
        left = None if duration_s is None else duration_s - (clock() - start)
        if left is not None and left <= 0:
            break
        msg = bus.recv(timeout=0.5 if left is None else min(left, 0.5))
        if msg is None:
            continue
        if record is not None:
            record.on_message_received(msg)
        if msg.is_error_frame:
            continue
        d = decoder.decode(msg.arbitration_id, bytes(msg.data), msg.is_remote_frame)
        if kinds and d.kind not in kinds:
            continue
        if nodes and d.node_id not in nodes:
            continue
        out.write(format_line(clock() - start, msg.arbitration_id, d) + "\n")
        out.flush()
        printed += 1
    return printed
