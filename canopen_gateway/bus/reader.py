"""The reader thread's handlers, one per COB-ID: what happens to a frame before the event loop.

Built once per node when the master installs its dispatch table (``BusDriver.handlers``), and
run on the reader thread for every frame of their COB-ID:

* ``tpdo_handler``: decodes a TPDO with its precompiled codec straight into the process image
  (the per-frame path: no wait on the event loop); the guarding-bit echo of a status word is
  posted to the loop;
* ``control_handler``: boot-up / heartbeat / guarding answer, EMCY and SDO answer of a node,
  posted to the loop stamped with the frame's receive time; a steady node's repeated heartbeat
  is posted without waking the loop;
* ``peer_frame_handler``: a frame another participant sent (NMT, SDO requests to our nodes, a
  pair's frames), posted to the loop with its data and times;
* ``unknown_handler``: any other frame, counted and warned; the node ids that talk are told to
  the loop once per COB-ID.

``post`` is the master's one hand-off to the event loop (``Master._post``); ``frame_time`` its
driver's bus clock of a frame.

Imports: canopen.connection_set (COB-ID words), bus.node.parts (types), canopen.cia301, pdo.codec (types), image
(types), runtime.ratelimit (types), python-can (types) and the standard library.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import can

from canopen_gateway.bus.node.parts import NodeParts
from canopen_gateway.canopen.cia301 import COB_LSS_MASTER, COB_SYNC
from canopen_gateway.canopen.connection_set import describe_cob_id, talking_node_id
from canopen_gateway.image import ProcessImage
from canopen_gateway.pdo.codec import TpdoCodec
from canopen_gateway.runtime.ratelimit import RateLimitedLog

Handler = Callable[[can.Message], None]
Post = Callable[..., None]
FrameTime = Callable[[can.Message], float]


def control_handler(
    p: NodeParts, kind: str, post: Post, dispatch: Callable[..., None], frame_time: FrameTime
) -> Handler:
    """A node's control frame (``kind``: nmt_ec, emcy, sdo) to ``dispatch`` on the loop."""
    last: list[bytes | None] = [None]  # the reader's own: the node's previous 700h frame

    def handle(msg: can.Message) -> None:
        if msg.is_remote_frame:
            if kind == "nmt_ec":  # another master's guarding RTR: a listening node counts it
                post(dispatch, p, "rtr", b"", msg.timestamp or time.time(), frame_time(msg))
            return
        data = bytes(msg.data)
        # a heartbeat repeating the previous one of a steady node changes nothing before
        # the node's deadline: no wake-up of the loop for it
        quiet = kind == "nmt_ec" and p.steady and data == last[0]
        last[0] = data
        post(
            dispatch, p, kind, data, msg.timestamp or time.time(), frame_time(msg),
            wake=not quiet,
        )  # fmt: skip

    return handle


def tpdo_handler(
    p: NodeParts,
    codec: TpdoCodec,
    image: ProcessImage,
    counters: dict[str, int],
    warn: RateLimitedLog,
    post: Post,
    echo: Callable[..., None],
    frame_time: FrameTime,
) -> Handler:
    """One TPDO of one node decoded into the image on the reader thread."""
    node = p.image
    rx = node.rx.new_cell()  # this handler's: written on the reader thread only
    decode, names, length, update = codec.decode, codec.names, codec.length, image.update
    pdo_listeners = image.pdo_listeners
    gb = p.settings.guarding_bit
    status_pos = names.index(p.node.status_signal) if gb and p.node.status_signal in names else -1
    status_mask = 1 << gb.status_bit if gb else 0

    def wrong_length(key: str, n: int, mapping: str) -> None:
        """The rate-limited warning of a TPDO of ``n`` bytes, not its mapping's ``length``;
        ``mapping`` ends the sentence (``"needs %d; ignored"``)."""
        text = "node %s: PDO 0x%03X with %d bytes, mapping " + mapping
        warn.warning(key, text, node.name, codec.cob_id, n, length)

    def handle(msg: can.Message) -> None:
        data = msg.data
        if msg.is_remote_frame:
            return
        n = len(data)
        if n < length:
            rx.pdo_too_short += 1
            counters["decode_errors"] += 1
            wrong_length("short_pdo", n, "needs %d; ignored")
            return
        if n > length:
            # CiA 301: a PDO longer than its mapping is processed (the mapped bytes)
            rx.pdo_too_long += 1
            counters["pdo_too_long"] += 1
            wrong_length("long_pdo", n, "has %d; extra bytes ignored")
        values = decode(data)
        # stamped with its receive time (bus clock), not when the reader got to it
        update(node, names, values, msg.timestamp or time.time(), rx, frame_time(msg))
        if pdo_listeners:
            raw = bytes(data)
            for listener in pdo_listeners:
                listener(node, codec.cob_id, raw)
        if status_pos >= 0:
            post(echo, p, 1 if values[status_pos] & status_mask else 0, frame_time(msg))

    return handle


def peer_frame_handler(post: Post, frame_time: FrameTime, fn: Callable[..., None], *args: Any) -> Handler:
    """A frame another participant sent (NMT, our heartbeat COB-ID, SDO requests to our nodes,
    a pair's frames): to ``fn`` on the loop, with its data, wall time and bus-clock time."""

    def handle(msg: can.Message) -> None:
        if not msg.is_remote_frame:
            post(fn, *args, bytes(msg.data), msg.timestamp or time.time(), frame_time(msg))

    return handle


def unknown_handler(
    counters: dict[str, int], warn: RateLimitedLog, post: Post, on_talking: Callable[..., None]
) -> Handler:
    """A frame no handler takes: counted and warned (rate-limited); the first frame of each
    COB-ID a node sends tells the loop that this node id talks (``BusPeers.on_talking``)."""
    seen: set[int] = set()  # the reader's own: unknown COB-IDs posted once

    def handle(msg: can.Message) -> None:
        cob = msg.arbitration_id
        if cob == COB_SYNC or cob == COB_LSS_MASTER:
            return  # SYNC from another master, LSS requests of another master
        counters["unknown_cob_id"] += 1
        if cob not in seen and len(seen) < 2048 and talking_node_id(cob) is not None:
            seen.add(cob)  # first sighting: which node ids talk (for "did not appear")
            post(on_talking, cob, msg.timestamp or time.time(), wake=False)
        warn.warning(
            "unknown_cob_id",
            "frame with unexpected COB-ID 0x%03X (%s) ignored",
            cob,
            describe_cob_id(cob),
        )

    return handle
