"""``canopen-gateway monitor``: candump for CANopen, one decoded line per frame.

Reads frames from a python-can bus and prints them as ``gateway.northbound.frames`` words them,
filtered by node (name or id) and kind (nmt, sync, time, emcy, pdo, sdo, heartbeat, lss,
other); stops after ``count`` lines or ``duration_s`` seconds, or at Ctrl-C.

Line: seconds since the start, COB-ID, node, service, text:
``   0.104  181  wire         TPDO1         position=1234.5 mm velocity=0 mm/s``

Imports: python-can, config, northbound.frames.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TextIO

import can

from gateway.northbound.frames import Decoded, FrameDecoder


def format_line(t: float, cob_id: int, d: Decoded) -> str:
    who = d.node or (f"id {d.node_id}" if d.node_id is not None else "-")
    return f"{t:8.3f}  {cob_id:03X}  {who:<12} {d.service:<13} {d.text}".rstrip()


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
) -> int:
    """Print decoded frames until ``count`` lines or ``duration_s``; returns the lines printed."""
    start = clock()
    printed = 0
    while count is None or printed < count:
        left = None if duration_s is None else duration_s - (clock() - start)
        if left is not None and left <= 0:
            break
        msg = bus.recv(timeout=0.5 if left is None else min(left, 0.5))
        if msg is None or msg.is_error_frame:
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
