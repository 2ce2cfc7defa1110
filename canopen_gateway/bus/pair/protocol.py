"""The vocabulary of a hot-standby pair's role machine (``flying_master.py``): the CiA 302-2
COB-IDs, the roles, what moves them, the actions the machine returns and the pair's times.

Imports: the standard library.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Literal, NamedTuple

# CiA 302-2 (NMT flying master): the COB-IDs of its services
COB_ACTIVE_MASTER_RESPONSE = 0x71  # [priority, node id]
COB_NEGOTIATION_REQUEST = 0x72
COB_ACTIVE_MASTER_REQUEST = 0x73
COB_CAPABLE_RESPONSE = 0x74  # [priority, node id]
COB_DETECT_CAPABLE = 0x75
COB_FORCE_NEGOTIATION = 0x76
FLYING_MASTER_COB_IDS = frozenset(
    {
        COB_ACTIVE_MASTER_RESPONSE,
        COB_NEGOTIATION_REQUEST,
        COB_ACTIVE_MASTER_REQUEST,
        COB_CAPABLE_RESPONSE,
        COB_DETECT_CAPABLE,
        COB_FORCE_NEGOTIATION,
    }
)


class Role(StrEnum):
    LISTENING = "listening"  # just started or back: is there an active master?
    NEGOTIATING = "negotiating"  # no active master heard: waiting for its time slot
    STANDBY = "standby"  # another master is active: listen only
    ACTIVE = "active"  # this gateway is the bus's NMT master
    ISOLATED = "isolated"  # cut off: its bus is down or it hears nobody; sends nothing
    DUPLICATE = "duplicate"  # another device has this gateway's pair id: it stays out


class Heard(StrEnum):
    """What moves the role (the columns of ``TRANSITIONS`` and ``DOES``)."""

    LOGICAL_HEARTBEAT = "logical heartbeat"  # 700h + master.node_id (or the active master's)
    FOREIGN_LOGICAL = "logical heartbeat of another sender"  # heard while active, echo off
    BETTER_CLAIM = "71h that wins"
    WORSE_CLAIM = "71h that loses"
    OUTBID = "71h that wins within our slot"
    MET_AFTER_CUT = "another master, met after a deaf spell"
    OWN_ID = "our own pair id from another device"
    NEGOTIATION = "72h"
    NEGOTIATION_WHILE_BACK = "72h, this gateway back from an outage"  # it lets them claim
    REQUEST = "73h"
    DETECT_CAPABLE = "75h"
    FORCE = "76h"
    DETECTION_OVER = "detection time over"
    SLOT_OVER = "time slot over"
    CLAIM_DUE = "time slot over while active"
    DETECT_DUE = "detect cycle over"
    ACTIVE_SILENT = "active master silent, traffic heard"
    UNHEARD = "active master silent, nothing heard since"
    DEAF = "nothing heard"
    LINK_LOST = "bus down"
    CANNOT_SEND = "this gateway cannot send"  # bus off, error passive, sends refused
    BUS_HEARD = "traffic heard"
    STALLED = "this gateway stalled"  # no event for longer than the take-over time
    CAPABLE = "74h"  # a master-capable device answered a 75h
    UNANSWERED = "its 75h drew no answer"  # timer: its frames do not reach the bus
    STEPPED_DOWN = "the active member says it no longer masters"  # its own heartbeat
    LEAVING = "this gateway stops"  # a planned hand-over (SIGTERM)


class PairError(RuntimeError):
    """Our own misuse of the machine: a role change the table does not define."""


class Send(NamedTuple):
    """Send this frame (11-bit ``cob_id``, ``data``)."""

    kind: Literal["send"]
    cob_id: int
    data: bytes


class RoleChanged(NamedTuple):
    """The role changed: start (``active``) or stop mastering the bus; ``reason`` for the log.
    ``fresh``: this gateway comes back from (or enters) an outage of its own (cut off, unable
    to send, stalled): what it knew of the nodes is forgotten, it listens as a fresh joiner."""

    kind: Literal["role"]
    role: Role
    previous: Role
    reason: str
    fresh: bool = False


class Notice(NamedTuple):
    """A line for the log (``key``: one line per key and episode is enough)."""

    kind: Literal["notice"]
    key: str
    text: str


Action = Send | RoleChanged | Notice


#: the NMT state byte of a member's own heartbeat says its role (CiA 301 7.2.8.3.2.2 states):
#: operational while it masters the bus, stopped while cut off, pre-operational otherwise
ROLE_STATE = {Role.ACTIVE: 0x05, Role.ISOLATED: 0x04}
NOT_ACTIVE_STATE = 0x7F
#: what the other member's own heartbeat says of its role
PEER_ROLE = {0x05: "active", 0x7F: "standby", 0x04: "isolated"}


@dataclass(frozen=True)
class PairTiming:
    """The times of the pair, in seconds (config ``master.redundancy``)."""

    takeover_s: float  # the active master's heartbeat missing this long: it is gone
    detect_s: float  # when listening: listen this long for an active master
    detect_cycle_s: float = 4.0  # CiA 302-2 1F90h:06: the active one's 76h this often
    priority_slot_s: float = 0.2  # CiA 302-2 1F90h:04, per priority level
    device_slot_s: float = 0.002  # CiA 302-2 1F90h:05, per node id
    heartbeat_s: float | None = None  # the logical heartbeat's period (None: takeover_s / 3)
    #: the longest the devices may be silent while the master is alive: the shortest period of
    #: a device that talks unasked (a heartbeat producer); None: none does
    talk_s: float | None = None
    #: nothing at all heard this long after a gateway began listening: the bus is silent (no
    #: active master: it negotiates); longer than a starting process stalls (1.9 s measured)
    silent_s: float = 2.0

    @property
    def heartbeat(self) -> float:
        return self.heartbeat_s if self.heartbeat_s is not None else self.takeover_s / 3

    @property
    def answer_s(self) -> float:
        """How long a 75h may wait for a 74h before this gateway's frames count as lost."""
        return 2 * self.heartbeat

    @property
    def doubt_s(self) -> float:
        """From the master's last sign: how long a standby that heard nothing since waits for a
        frame before it counts itself cut off (a device talking unasked must have talked)."""
        talk = self.talk_s if self.talk_s is not None else 0.0
        return max(2 * self.takeover_s, 3 * self.heartbeat + talk)

    def slot_s(self, priority: int, node_id: int) -> float:
        """CiA 302-2 time slot: how long a candidate waits before it claims."""
        return priority * self.priority_slot_s + node_id * self.device_slot_s

    def worst_takeover_s(self, priority: int, node_id: int) -> float | None:
        """The longest the logical master is silent when the gateway (``priority``,
        ``node_id``) takes over from a dead active one, counted from the heartbeat the old one
        may have been about to send: the standby negotiates once the master was silent for
        ``takeover_s`` and a frame was heard after two heartbeats (the devices' next
        ``talk_s``), then claims at the end of its slot. None: no device talks unasked, so a
        standby cannot tell a dead master from its own cut cable, and does not take over."""
        if self.talk_s is None:
            return None
        negotiates = max(self.takeover_s, 2 * self.heartbeat + self.talk_s)
        return negotiates + self.slot_s(priority, node_id) + self.heartbeat


@dataclass(frozen=True)
class Claim:
    """A 71h heard from another gateway, and when."""

    priority: int
    node_id: int
    at_s: float


def wins(a: tuple[int, int], b: tuple[int, int]) -> bool:
    """True when claim ``a`` = (priority, node id) wins against ``b``: lower first."""
    return a < b
