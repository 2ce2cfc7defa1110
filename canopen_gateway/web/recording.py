"""The console's bus recording (``GET /api/monitor/record?seconds=S&format=asc[&network=N]``):
the frames the gateway receives on one network's bus (``network``, the first by default; 400
for a network it does not have) for S seconds (at most ``MAX_SECONDS``), downloaded as a trace
file in python-can's writer of the format asked for (.asc Vector ASCII, .blf Vector binary,
.trc PCAN-View, .log candump, .csv), the same files as ``canopen-gateway monitor --record``;
``canopen-gateway decode -c CONFIG FILE`` reads them back in CANopen words (``--network`` the
recorded one: node ids are a network's own). With several networks the file's name carries the
network's (``<gateway>-<network>-bus-<time>.asc``).

Rule 1 (the CAN reader thread): the tap only appends the ``can.Message`` to the recording's
list, bounded (``MAX_FRAMES``: later frames are counted, not kept), under a lock; it is
installed on the driver only while a recording runs. Rule 2 (the event loop): the request
waits its seconds, removes the tap and has the file written in a worker thread
(``asyncio.to_thread``): the loop never formats a trace. At most ``MAX_RECORDINGS`` at a time.

Frames the gateway sends are not tapped (as on the monitor page): the recording is what the
gateway receives.

Imports: python-can, bus.trace (the trace writer), http.server (request/response types), web.monitor
(FrameSource, the driver as a tap source).
"""

from __future__ import annotations

import asyncio
import json
import tempfile
import threading
import time
from http import HTTPStatus
from pathlib import Path

import can

from canopen_gateway.bus.trace import trace_writer
from canopen_gateway.http.server import Request, Response
from canopen_gateway.web.monitor import FrameSource

FORMATS = ("asc", "blf", "trc", "log", "csv")
MAX_SECONDS = 60.0
DEFAULT_SECONDS = 10.0
MAX_FRAMES = 200_000  # about 20 s of a saturated 1 Mbit/s bus; later frames are counted
MAX_RECORDINGS = 2


class Recording:
    """One recording's frames (the tap appends them on the reader thread)."""

    def __init__(self) -> None:
        self.frames: list[can.Message] = []
        self.dropped = 0
        self._lock = threading.Lock()

    def on_frame(self, msg: can.Message) -> None:
        with self._lock:
            if len(self.frames) < MAX_FRAMES:
                self.frames.append(msg)
            else:
                self.dropped += 1

    def take(self) -> list[can.Message]:
        with self._lock:
            return list(self.frames)


def write_trace(frames: list[can.Message], fmt: str) -> tuple[bytes, int]:
    """The frames as a file of python-can's writer for ``fmt`` (its suffix), and how many of
    them the format cannot hold (remote frames in a .trc)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"trace.{fmt}"
        writer = trace_writer(str(path))
        for msg in frames:
            writer.on_message_received(msg)
        writer.stop()
        return path.read_bytes(), writer.left_out


class BusRecorder:
    """The recordings of the console (see the module docstring)."""

    def __init__(
        self, sources: dict[str, FrameSource | None], gateway_name: str, headers: dict[str, str]
    ):
        #: each network's bus driver (a tap source), in configured order
        self.sources = sources
        self.name = gateway_name
        self.headers = headers
        self.running = 0

    async def answer(self, request: Request) -> Response:
        network = request.query.get("network") or next(iter(self.sources), "")
        if network not in self.sources:
            return _json(HTTPStatus.BAD_REQUEST, "bad_request",
                         f"network: no network named {network!r}; networks: {', '.join(self.sources)}")  # fmt: skip
        source = self.sources[network]
        fmt = request.query.get("format", "asc").lower().lstrip(".")
        try:
            seconds = float(request.query.get("seconds", DEFAULT_SECONDS))
        except ValueError:
            seconds = -1.0
        if fmt not in FORMATS or not 0 < seconds <= MAX_SECONDS:
            return _json(HTTPStatus.BAD_REQUEST, "bad_request",
                         f"format: one of {', '.join(FORMATS)}; seconds: more than 0, at most {MAX_SECONDS:g}")  # fmt: skip
        if source is None:
            return _json(HTTPStatus.SERVICE_UNAVAILABLE, "busy", "this gateway has no bus to record")
        if self.running >= MAX_RECORDINGS:
            return _json(HTTPStatus.SERVICE_UNAVAILABLE, "busy", f"at most {MAX_RECORDINGS} recordings at a time")
        recording = Recording()
        self.running += 1
        started = time.time()
        source.add_tap(recording.on_frame)
        try:
            await asyncio.sleep(seconds)
        finally:
            source.remove_tap(recording.on_frame)
            self.running -= 1
        body, left_out = await asyncio.to_thread(write_trace, recording.take(), fmt)
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(started))
        which = f"{network}-" if len(self.sources) > 1 else ""
        name = f"{self.name}-{which}bus-{stamp}.{fmt}".replace('"', "")
        headers = {**self.headers, "Content-Disposition": f'attachment; filename="{name}"',
                   "X-Frames-Dropped": str(recording.dropped),
                   "X-Frames-Left-Out": str(left_out)}  # fmt: skip
        return Response(HTTPStatus.OK, body, "application/octet-stream", headers=headers)


def _json(status: HTTPStatus, kind: str, message: str) -> Response:
    return Response(status, json.dumps({"error": kind, "message": message}).encode() + b"\n",
                    "application/json")  # fmt: skip
