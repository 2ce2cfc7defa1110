"""The SDO transfers a pair's standby hears the active gateway make, and the ones it must abort
when it takes the bus over (CiA 301 7.2.4.3).

A transfer is open from its initiate request until its last answer, not only while a request
waits for its answer: a segmented download between two segments, a segmented upload between
two segment requests, a block transfer within or between its sub-blocks or before its end
leave the device's SDO server waiting for the next request of a client that is gone (a device
then refuses every new transfer, or takes the new client's first request for the old
transfer's next). At a take-over each transfer left open is aborted once, before the new
active gateway sends that node anything else, naming the object of its initiate request
(0000h:00 when the standby joined within it), with 05040000h "SDO protocol timed out" (the
code a client gives when its transfer timed out, which is what became of it: CiA 302-2 names
no code of its own for it).

What ends a transfer, by the command byte of each frame (ccs / scs: its bits 5-7):

======================  =========================================  ===========================
transfer                opened by the client's                     ended by
======================  =========================================  ===========================
expedited download      initiate download, e = 1 (ccs 1)           the server's answer (60h)
segmented download      initiate download, e = 0 (ccs 1)           the answer (scs 1) to the
                                                                   segment with c = 1
upload                  initiate upload (ccs 2)                    an expedited answer (scs 2,
                                                                   e = 1), or the segment
                                                                   (scs 0) with c = 1
block download          initiate block download (ccs 6, cs 0)      the end answer (A1h)
block upload            initiate block upload (ccs 5, cs 0)        the client's end answer (A1h)
any                     -                                          an abort (80h) of either side
======================  =========================================  ===========================

Within a block download the client's frames are segments (a sequence number, bit 7 the last),
within a block upload the server's: they are read as such from the initiate answer (and the
client's start, A3h) until the block's acknowledge (A2h) after the last segment. A block upload
the server answers with an initiate upload answer (scs 2: below its protocol switch threshold)
goes on as an upload.

Rule: pure; the master feeds it the frames heard on 600h/580h + node id while it stands by
and sends what ``abort_left_open`` returns.

Imports: bus.sdo.client (the abort frame), canopen.cia301 and the standard library.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen_gateway.bus.sdo.client import abort_frame
from canopen_gateway.canopen.cia301 import COB_SDO_RX, SDO_ABORT_TIMEOUT

EXPEDITED, DOWNLOAD, UPLOAD, BLOCK_DOWN, BLOCK_UP, JOINED = (
    "expedited download", "segmented download", "upload", "block download", "block upload",
    "transfer joined within",
)  # fmt: skip
ABORT = 0x80  # CiA 301 7.2.4.3.17: abort transfer (ccs / scs 4)


@dataclass
class HeardTransfer:
    """One node's transfer as heard: its kind, the object of its initiate request, whether its
    raw segments are running (a block transfer) and whether the last one went."""

    kind: str
    obj: tuple[int, int] | None  # (index, sub); None: joined within the transfer
    segments: bool = False
    last: bool = False


def _obj(data: bytes) -> tuple[int, int] | None:
    return (int.from_bytes(data[1:3], "little"), data[3]) if len(data) >= 4 else None


class HeardSdo:
    """The transfers the other gateway has open, per node id (see the module docstring)."""

    def __init__(self) -> None:
        self.open: dict[int, HeardTransfer] = {}

    def on_request(self, node_id: int, data: bytes) -> None:
        """A client request heard on 600h + node id (the other gateway's)."""
        if not data:
            return
        cmd, t = data[0], self.open.get(node_id)
        if t is not None and t.kind == BLOCK_DOWN and t.segments and cmd != ABORT:
            t.last = bool(cmd & 0x80)  # a segment: its sequence number, bit 7 the last
            return
        ccs = cmd >> 5
        if ccs == 4:
            self.open.pop(node_id, None)
        elif ccs == 1:
            self.open[node_id] = HeardTransfer(EXPEDITED if cmd & 0x02 else DOWNLOAD, _obj(data))
        elif ccs == 2:
            self.open[node_id] = HeardTransfer(UPLOAD, _obj(data))
        elif ccs == 6 and not cmd & 0x01:
            self.open[node_id] = HeardTransfer(BLOCK_DOWN, _obj(data))
        elif ccs == 5 and not cmd & 0x03:
            self.open[node_id] = HeardTransfer(BLOCK_UP, _obj(data))
        elif t is None:
            self.open[node_id] = HeardTransfer(JOINED, None, last=ccs == 0 and bool(cmd & 0x01))
        elif ccs == 0:
            t.last = bool(cmd & 0x01)  # a download segment: c = 1 is the last
        elif ccs == 5 and cmd & 0x03 == 1:
            self.open.pop(node_id)  # block upload: the client's end answer
        elif ccs == 5 and t.kind == BLOCK_UP:
            t.segments = cmd & 0x03 == 3 or (cmd & 0x03 == 2 and not t.last)  # start / ack

    def on_response(self, node_id: int, data: bytes) -> None:
        """A server answer heard on 580h + node id."""
        t = self.open.get(node_id)
        if t is None or not data:
            return
        cmd = data[0]
        if t.kind == BLOCK_UP and t.segments and cmd != ABORT:
            t.last = bool(cmd & 0x80)  # a segment of the server's
            return
        scs = cmd >> 5
        done = (
            scs == 4
            or (t.kind == EXPEDITED and scs == 3)
            or (scs == 1 and t.last)  # the last download segment answered
            or (t.kind in (UPLOAD, BLOCK_UP, JOINED) and scs == 2 and bool(cmd & 0x02))  # expedited
            or (t.kind in (UPLOAD, JOINED) and scs == 0 and bool(cmd & 0x01))  # the last segment
            or (scs == 5 and cmd & 0x03 == 1)  # block download: the end answer
        )
        if done:
            self.open.pop(node_id)
        elif t.kind == BLOCK_UP and scs == 2:
            t.kind = UPLOAD  # below the server's protocol switch threshold: an upload
        elif t.kind == BLOCK_DOWN and scs == 5:
            t.segments = cmd & 0x03 == 0 or (cmd & 0x03 == 2 and not t.last)  # initiate / ack

    def abort_left_open(self) -> list[tuple[int, bytes, str]]:
        """At a take-over: (COB-ID, abort frame, log text) for each transfer left open, once;
        then nothing is open."""
        out = []
        for node_id, t in sorted(self.open.items()):
            index, sub = t.obj or (0, 0)
            # SDO protocol timed out (CiA 301 7.2.4.3.17): the transfer's client is gone
            frame = abort_frame(index, sub, SDO_ABORT_TIMEOUT)
            text = f"pair: SDO {t.kind} of {index:04X}h:{sub} left open on node id {node_id} aborted"
            out.append((COB_SDO_RX + node_id, frame, text))
        self.open.clear()
        return out
