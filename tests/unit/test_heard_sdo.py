"""The SDO transfers a pair's standby hears (canopen_gateway.bus.pair.heard_sdo): a transfer is
open from its first frame to its last, whatever its kind, and a take-over aborts each one left open
once, naming its object.

The expedited and segmented transfers are the wire of an independent stack: python canopen's
SDO client against its SDO server (a LocalNode) on a virtual bus. The block transfers (which
canopen's server does not serve) are scripted from CiA 301 7.2.4.3.9 to 7.2.4.3.16. Every
transfer is cut after each of its frames: open at every cut but before its first frame and
after its last.
"""

from __future__ import annotations

import threading
import uuid

import can
import canopen
import pytest
from canopen.objectdictionary import ObjectDictionary, ODVariable
from canopen.objectdictionary.datatypes import VISIBLE_STRING

from canopen_gateway.bus.pair.heard_sdo import HeardSdo
from canopen_gateway.canopen.cia301 import COB_SDO_RX, COB_SDO_TX

NODE_ID = 5
TEXT_OBJ = (0x2000, 0x00)  # a VISIBLE_STRING the test's LocalNode holds (rw)
ABORT_TIMEOUT = bytes((0x00, 0x00, 0x04, 0x05))  # 05040000h, little-endian

Wire = list[tuple[int, bytes]]


class Tap(can.Listener):
    def __init__(self) -> None:
        self.frames: Wire = []
        self.lock = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id in (COB_SDO_RX + NODE_ID, COB_SDO_TX + NODE_ID):
            with self.lock:
                self.frames.append((msg.arbitration_id, bytes(msg.data)))


def canopen_wire(download: bytes | None) -> Wire:
    """The frames of one transfer of 2000h:00 between python canopen's SDO client and server:
    a download of ``download``, or an upload (None) of the 20 characters the server holds
    (CiA 301: an initiate request and answer, then a request and an answer per 7 bytes)."""
    size = 20 if download is None else len(download)
    expected = 2 if size <= 4 and download is not None else 2 + 2 * -(-size // 7)
    channel = f"heardsdo-{uuid.uuid4().hex}"
    od = ObjectDictionary()
    var = ODVariable("text", *TEXT_OBJ)
    var.data_type, var.access_type = VISIBLE_STRING, "rw"
    od.add_object(var)
    server_net, client_net = canopen.Network(), canopen.Network()
    for net in (server_net, client_net):
        net.NOTIFIER_CYCLE = 0.01  # their readers' receive timeout: a quick stop
    server_net.connect(interface="virtual", channel=channel)
    client_net.connect(interface="virtual", channel=channel)
    tap = can.Bus(interface="virtual", channel=channel)
    wire = Tap()
    notifier = can.Notifier(tap, [wire], timeout=0.01)
    try:
        local = canopen.LocalNode(NODE_ID, od)
        server_net.add_node(local)
        local.set_data(*TEXT_OBJ, b"ABCDEFGHIJKLMNOPQRST")
        remote = canopen.RemoteNode(NODE_ID, od)
        client_net.add_node(remote)
        if download is None:
            remote.sdo.upload(*TEXT_OBJ)
        else:
            remote.sdo.download(*TEXT_OBJ, download)
        pause = threading.Event()
        for _ in range(500):  # the tap's thread has the last frame soon after the client
            with wire.lock:
                if len(wire.frames) >= expected:
                    break
            pause.wait(0.01)
    finally:
        notifier.stop()
        tap.shutdown()
        client_net.disconnect()
        server_net.disconnect()
    with wire.lock:
        return list(wire.frames)


def _seg(seq: int, last: bool = False) -> bytes:
    return bytes([seq | (0x80 if last else 0)]) + b"ABCDEFG"


#: CiA 301 7.2.4.3.9-12: a block download of 10 bytes of 2000h:00 in one sub-block of two
#: segments (size indicated, CRC supported), then its end
BLOCK_DOWNLOAD: Wire = [
    (COB_SDO_RX + NODE_ID, bytes((0xC6, 0x00, 0x20, 0x00, 10, 0, 0, 0))),  # initiate, s, cc
    (COB_SDO_TX + NODE_ID, bytes((0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0))),  # blksize 127
    (COB_SDO_RX + NODE_ID, _seg(1)),
    (COB_SDO_RX + NODE_ID, _seg(2, last=True)),
    (COB_SDO_TX + NODE_ID, bytes((0xA2, 2, 127, 0, 0, 0, 0, 0))),  # ackseq 2
    (COB_SDO_RX + NODE_ID, bytes((0xC1 | 4 << 2, 0x12, 0x34, 0, 0, 0, 0, 0))),  # end, n = 4, CRC
    (COB_SDO_TX + NODE_ID, bytes((0xA1, 0, 0, 0, 0, 0, 0, 0))),
]
#: CiA 301 7.2.4.3.13-16: a block upload of 2000h:00 in two sub-blocks, then its end
BLOCK_UPLOAD: Wire = [
    (COB_SDO_RX + NODE_ID, bytes((0xA4, 0x00, 0x20, 0x00, 2, 0, 0, 0))),  # blksize 2, pst 0
    (COB_SDO_TX + NODE_ID, bytes((0xC6, 0x00, 0x20, 0x00, 20, 0, 0, 0))),  # size 20
    (COB_SDO_RX + NODE_ID, bytes((0xA3, 0, 0, 0, 0, 0, 0, 0))),  # start
    (COB_SDO_TX + NODE_ID, _seg(1)),
    (COB_SDO_TX + NODE_ID, _seg(2)),
    (COB_SDO_RX + NODE_ID, bytes((0xA2, 2, 2, 0, 0, 0, 0, 0))),  # ack, next blksize 2
    (COB_SDO_TX + NODE_ID, _seg(1, last=True)),
    (COB_SDO_RX + NODE_ID, bytes((0xA2, 1, 2, 0, 0, 0, 0, 0))),
    (COB_SDO_TX + NODE_ID, bytes((0xC1 | 1 << 2, 0x12, 0x34, 0, 0, 0, 0, 0))),  # end, CRC
    (COB_SDO_RX + NODE_ID, bytes((0xA1, 0, 0, 0, 0, 0, 0, 0))),
]


def heard(frames: Wire) -> HeardSdo:
    h = HeardSdo()
    for cob, data in frames:
        if cob == COB_SDO_RX + NODE_ID:
            h.on_request(NODE_ID, data)
        else:
            h.on_response(NODE_ID, data)
    return h


@pytest.mark.parametrize(
    ("kind", "frames"),
    [
        ("expedited download", lambda: canopen_wire(b"ABC")),
        ("segmented download", lambda: canopen_wire(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ")),
        ("segmented upload", lambda: canopen_wire(None)),
        ("block download", lambda: BLOCK_DOWNLOAD),
        ("block upload", lambda: BLOCK_UPLOAD),
    ],
)
def test_a_transfer_is_open_from_its_first_frame_to_its_last(kind: str, frames: object) -> None:
    wire = frames()  # type: ignore[operator]
    assert len(wire) >= 2, wire
    for cut in range(len(wire) + 1):
        open_ = NODE_ID in heard(wire[:cut]).open
        assert open_ == (0 < cut < len(wire)), (kind, cut, wire[:cut])


def test_a_segmented_download_left_between_two_segments_is_aborted_once_naming_its_object() -> None:
    wire = canopen_wire(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ")
    # cut after the server answered a segment that was not the last: no request awaits an
    # answer, yet the server waits for the next segment
    cut = next(i for i in range(3, len(wire)) if wire[i - 1][0] == COB_SDO_TX + NODE_ID)
    h = heard(wire[:cut])
    assert h.open[NODE_ID].kind == "segmented download"
    frames = h.abort_left_open()
    assert [(c, d) for c, d, _ in frames] == [
        (COB_SDO_RX + NODE_ID, bytes((0x80, 0x00, 0x20, 0x00)) + ABORT_TIMEOUT)
    ]
    assert "segmented download of 2000h:0 left open on node id 5 aborted" in frames[0][2]
    assert h.abort_left_open() == []  # once


def test_a_transfer_joined_mid_way_is_aborted_without_naming_a_wrong_object() -> None:
    h = HeardSdo()
    h.on_request(NODE_ID, bytes((0x10, 0x41, 0x42, 0x43, 0x44, 0x45, 0x46, 0x47)))  # a segment
    h.on_response(NODE_ID, bytes((0x30, 0, 0, 0, 0, 0, 0, 0)))  # answered, not the last
    assert [(c, d) for c, d, _ in h.abort_left_open()] == [
        (COB_SDO_RX + NODE_ID, bytes((0x80, 0, 0, 0)) + ABORT_TIMEOUT)
    ]


def test_an_abort_of_either_side_ends_the_transfer_and_an_answered_expedited_one_leaves_nothing() -> None:
    h = HeardSdo()
    h.on_request(NODE_ID, bytes((0x21, 0x00, 0x20, 0x01, 10, 0, 0, 0)))
    h.on_response(NODE_ID, bytes((0x80, 0x00, 0x20, 0x01)) + bytes((0, 0, 0x02, 0x06)))
    h.on_request(6, bytes((0x40, 0x17, 0x10, 0x00, 0, 0, 0, 0)))
    h.on_response(6, bytes((0x4B, 0x17, 0x10, 0x00, 0x64, 0, 0, 0)))
    h.on_request(7, bytes((0xC6, 0x00, 0x20, 0x00, 10, 0, 0, 0)))
    h.on_response(7, bytes((0xA4, 0x00, 0x20, 0x00, 127, 0, 0, 0)))
    h.on_request(7, bytes((0x80, 0x00, 0x20, 0x00)) + ABORT_TIMEOUT)  # the client gave up
    assert h.open == {}
    # a block upload the server answers as an upload (below its protocol switch threshold)
    h.on_request(8, bytes((0xA4, 0x00, 0x20, 0x00, 127, 21, 0, 0)))
    h.on_response(8, bytes((0x41, 0x00, 0x20, 0x00, 20, 0, 0, 0)))
    assert h.open[8].kind == "upload"
    h.on_request(8, bytes((0x60, 0, 0, 0, 0, 0, 0, 0)))
    h.on_response(8, bytes((0x01,)) + b"ABCDEFG")  # c = 1: the last segment
    assert h.open == {}
