"""Who else is on the bus: another master, other SDO clients, node ids nobody configured.

A shared bus is normal (a commissioning tool reading objects of our nodes); two masters are
not (two gateways with the same node id fight over the nodes: guarding-bit faults, lost
nodes). This module tells them apart from the frames the master hands it, and says so in
words:

=========================================  ==============================================
frame                                      meaning
=========================================  ==============================================
NMT command (COB-ID 000h) we did not send  another master: a warning (rate-limited)
heartbeat on our own COB-ID (700h + our    another device with our node id: a warning
id) with a payload we did not send
SDO request (600h + id) to one of our      another SDO client (a commissioning tool):
nodes                                      info, once per node and period
frame of a node id that is not configured  remembered; a node that does not appear
                                           points at the ids that talk instead
=========================================  ==============================================

"Did we send it": a python-can bus does not receive its own frames unless
``receive_own_messages`` is set; then every frame on those COB-IDs came from elsewhere. With
the echo on, each frame received on them takes one frame with the same COB-ID and payload that
we sent in the last ``echo_window_s`` (its echo); a frame that finds none is another
participant's. So a second gateway with our node id, operational like us, is told apart by
count: the bus carries two heartbeats for each one we sent. What waits for its echo is bounded
by construction: frames older than the window are dropped whenever we send or receive, and at
most ``ECHO_PENDING_MAX`` are kept (the oldest goes first).

Sans-I/O: the master calls it on the event loop (one owner), with the time; it returns the
text of a line to log or None, and keeps counts for /healthz, the web console and /metrics.
COB-ID functions: CiA 301 7.3.3 (pre-defined connection set).

Imports: canopen_gateway.canopen.cia301, canopen_gateway.canopen.connection_set, canopen_gateway.canopen.states and the
standard library only.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from canopen_gateway.canopen.cia301 import COB_NMT, COB_NMT_EC, COB_SDO_RX, COB_SYNC
from canopen_gateway.canopen.connection_set import describe_cob_id, talking_node_id
from canopen_gateway.canopen.states import NMT_BY_CODE, NmtState

NMT_COB_ID = COB_NMT
SYNC_COB_ID = COB_SYNC
SDO_REQUEST_BASE = COB_SDO_RX  # SDO client -> server (RSDO of the node)
HEARTBEAT_BASE = COB_NMT_EC
#: our frames waiting for their echo, at most (the oldest goes first): an echo window (1 s) of
#: NMT commands to every node one by one (127) and heartbeats every 10 ms (100) fits
ECHO_PENDING_MAX = 256


def _state_name(byte: int) -> str:
    try:
        return NmtState(byte & 0x7F).name.lower().replace("_", "-")
    except ValueError:
        return f"state 0x{byte:02X}"


@dataclass
class Sighting:
    """What was seen of one kind: how often, when last (wall clock), and the last detail."""

    count: int = 0
    last_wall: float | None = None
    detail: str = ""

    def doc(self) -> dict[str, Any]:
        return {"count": self.count, "last": self.last_wall, "detail": self.detail}


@dataclass
class TalkingId:
    cob_ids: set[int] = field(default_factory=set)
    last_wall: float | None = None


class BusPeers:
    """The other participants of the bus as the master saw them (see the module docstring)."""

    def __init__(
        self,
        own_node_id: int,
        configured_ids: set[int],
        *,
        echo: bool = False,
        echo_window_s: float = 1.0,
    ):
        self.own_node_id = own_node_id
        self.configured_ids = configured_ids
        self.echo = echo
        self.echo_window_s = echo_window_s
        #: (time sent, COB-ID, payload) of our frames the echo has not brought back yet
        self._sent: deque[tuple[float, int, bytes]] = deque(maxlen=ECHO_PENDING_MAX)
        #: "nmt", "heartbeat": another master's frames
        self.other_master: dict[str, Sighting] = {}
        #: node name -> SDO requests of other clients to that node
        self.sdo_clients: dict[str, Sighting] = {}
        self.talking: dict[int, TalkingId] = {}

    # -- what we sent (only matters when the bus echoes our own frames)
    def sent(self, cob_id: int, data: bytes, now: float) -> None:
        if self.echo and cob_id in (NMT_COB_ID, HEARTBEAT_BASE + self.own_node_id):
            self._expire(now)
            self._sent.append((now, cob_id, bytes(data)))

    @property
    def echoes_pending(self) -> int:
        """Frames we sent whose echo has not come back (yet) within the window."""
        return len(self._sent)

    def _expire(self, now: float) -> None:
        sent = self._sent
        while sent and now - sent[0][0] > self.echo_window_s:
            sent.popleft()

    def _ours(self, cob_id: int, data: bytes, now: float) -> bool:
        """The echo of a frame we sent: takes that frame (each echo answers one)."""
        self._expire(now)
        sent = self._sent
        for i, (_, cob, payload) in enumerate(sent):
            if cob == cob_id and payload == data:
                del sent[i]
                return True
        return False

    def _see(self, table: dict[str, Sighting], kind: str, wall: float, detail: str) -> None:
        s = table.setdefault(kind, Sighting())
        s.count += 1
        s.last_wall = wall
        s.detail = detail

    # -- frames
    def on_nmt(self, data: bytes, wall: float, now: float) -> str | None:
        """An NMT command on the bus: the text of a warning if another master sent it."""
        if self._ours(NMT_COB_ID, data, now):
            return None
        if len(data) >= 2:
            command = NMT_BY_CODE.get(data[0], f"command 0x{data[0]:02X}")
            target = "every node (id 0)" if data[1] == 0 else f"node id {data[1]}"
            detail = f"NMT {command} to {target}"
        else:
            detail = f"NMT frame {data.hex(' ') or '(empty)'}"
        self._see(self.other_master, "nmt", wall, detail)
        return (
            f"another master on the bus: {detail}, which this gateway did not send; "
            "two masters fight over the nodes (states, guarding): keep one"
        )

    def on_own_heartbeat(self, data: bytes, wall: float, now: float) -> str | None:
        """A frame on our own heartbeat COB-ID: the text of a warning if we did not send it."""
        if self.echo and self._ours(HEARTBEAT_BASE + self.own_node_id, data, now):
            return None
        state = _state_name(data[0]) if data else "no state byte"
        cob = HEARTBEAT_BASE + self.own_node_id
        detail = f"heartbeat 0x{cob:03X} ({state}) from another device"
        self._see(self.other_master, "heartbeat", wall, detail)
        return (
            f"another device uses this gateway's node id {self.own_node_id}: {detail}; "
            "two masters with one node id: change master.node_id of one of them"
        )

    def on_sdo_request(self, node: str, node_id: int, data: bytes, wall: float) -> str:
        """An SDO request of another client to one of our nodes (normal on a shared bus)."""
        what = _sdo_request_text(data)
        self._see(self.sdo_clients, node, wall, what)
        return (
            f"another SDO client talks to node {node} (id {node_id}): {what} "
            "(a commissioning tool? normal on a shared bus)"
        )

    def on_talking(self, cob_id: int, wall: float) -> None:
        """A frame of a node id that is not configured (first sightings per COB-ID)."""
        node_id = talking_node_id(cob_id)
        if node_id is None or node_id in self.configured_ids:
            return
        t = self.talking.setdefault(node_id, TalkingId())
        t.cob_ids.add(cob_id)
        t.last_wall = wall

    def admit(self, node_id: int) -> bool:
        """``node_id`` belongs here (a hot-standby pair's partner): not an unconfigured node that
        talks. False when it was known already."""
        if node_id in self.configured_ids:
            return False
        self.configured_ids.add(node_id)
        self.talking.pop(node_id, None)
        return True

    # -- reports
    def talking_hint(self, heard: Sequence[str] = ()) -> str:
        """``; node ids talking on this bus but not configured: 1 (TPDO1 0x181, heartbeat 0x701)``.
        ``heard``: the configured nodes that are heard (alive): when they are, the bus works and
        only the ids outside the config are news."""
        if not self.talking and heard:
            return (
                "; no node id outside the config talks on this bus (configured nodes heard: "
                + ", ".join(heard)
                + "; is this device powered and connected?)"
            )
        if not self.talking:
            return "; no other node id talks on this bus either (wiring, bit rate, power?)"
        parts = []
        for node_id in sorted(self.talking)[:8]:
            cobs = sorted(self.talking[node_id].cob_ids)[:3]
            kinds = ", ".join(f"{describe_cob_id(c).split(' of ')[0]} 0x{c:03X}" for c in cobs)
            parts.append(f"{node_id} ({kinds})")
        more = f" and {len(self.talking) - 8} more" if len(self.talking) > 8 else ""
        return (
            "; node ids talking on this bus but not configured: "
            + ", ".join(parts)
            + more
            + " (a wrong node_id in the config?)"
        )

    def doc(self) -> dict[str, Any]:
        """For /healthz and the web console."""
        return {
            "other_master": {k: v.doc() for k, v in sorted(self.other_master.items())},
            "other_sdo_clients": {k: v.doc() for k, v in sorted(self.sdo_clients.items())},
            "unconfigured_node_ids": sorted(self.talking),
        }


# CiA 301 7.2.4.3: the client command specifier (bits 7..5 of byte 0) of an SDO request
_SDO_CCS = {
    0: "download segment",
    1: "download",
    2: "upload",
    3: "upload segment",
    4: "abort",
    5: "block upload",
    6: "block download",
}


def _sdo_request_text(data: bytes) -> str:
    if not data:
        return "empty SDO frame"
    ccs = data[0] >> 5
    name = _SDO_CCS.get(ccs, f"command 0x{data[0]:02X}")
    if ccs in (1, 2, 4, 5, 6) and len(data) >= 4:
        index = data[1] | (data[2] << 8)
        return f"{name} of 0x{index:04X}:{data[3]:02X}"
    return name
