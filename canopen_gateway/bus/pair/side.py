"""The pair's side of the master (``bus/master.py``): what only a member of a hot-standby pair
does, as a base class of ``Master``. It installs the pair's receivers (the CiA 302-2 frames, the
logical heartbeat, the peer's and a third-party master's heartbeats, the RPDOs the active
gateway sends), feeds the member (``member.py``) and starts or stops mastering the nodes when
the role changes. ``mastering`` is the one role gate of the master's send path
(``_send_as_master``) and of the command service (``require_active``, which ``require_bus``
calls); ``role``, ``pair`` and the ``pair_*`` properties are read-only views (the app's health
and metrics, the command service's ``role``).

Imports: bus.pair.member, bus.pair.flying_master, bus.pair.heard_sdo (types), bus.node (types;
listening), bus.sdo.waiters (types), bus.driver / bus.bus_peers (types), canopen.cia301, config
(types), errors, python-can, logging.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import can

from canopen_gateway.bus.bus_peers import BusPeers
from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.bus.node import listening
from canopen_gateway.bus.node.parts import NodeParts
from canopen_gateway.bus.pair.flying_master import FlyingMaster, Role, RoleChanged
from canopen_gateway.bus.pair.heard_sdo import HeardSdo
from canopen_gateway.bus.pair.member import PairMember
from canopen_gateway.bus.sdo.waiters import SdoWaiters
from canopen_gateway.canopen.cia301 import COB_NMT_EC
from canopen_gateway.config import Config
from canopen_gateway.errors import NotActive

log = logging.getLogger("gateway.master")

#: the master's heartbeat: operational (CiA 301 7.2.8.3.2.2)
MASTER_HEARTBEAT = b"\x05"


class NoPair:
    """The null member of a gateway outside a pair: it always masters the bus; the master
    calls it where it calls a pair's member, and nothing happens."""

    machine: FlyingMaster | None = None
    role: str | None = None
    conflict: str | None = None
    peer_heartbeat_s: float | None = None

    def __init__(self) -> None:
        self.role_listeners: list[Callable[[str, str], None]] = []

    def known_ids(self) -> set[int]:
        return set()

    def check(self) -> None:
        pass

    def start(self, loop: Any) -> None:
        pass

    def stop(self) -> None:
        pass

    def on_link(self, state: str) -> None:
        pass

    def hand_over(self) -> bool:
        return False


class PairSide:
    """The pair-only part of ``Master`` (the attributes below are the master's)."""

    cfg: Config
    driver: BusDriver
    member: PairMember | NoPair
    mastering: bool
    nodes: dict[str, NodeParts]
    peers: BusPeers
    clock: Callable[[], float]
    heard_sdo: HeardSdo
    _waiting: SdoWaiters

    def _execute(self, p: NodeParts, outs: list[Any]) -> None:
        raise NotImplementedError

    def _peer_frame(self, fn: Callable[..., None], *args: Any) -> Callable[[can.Message], None]:
        raise NotImplementedError

    @property
    def in_pair(self) -> bool:
        """This gateway is a member of a hot-standby pair (``master.redundancy``)."""
        return isinstance(self.member, PairMember)

    def _install_pair_handlers(
        self,
        install: Callable[[int, str, Callable[[can.Message], None]], None],
        taken: dict[int, str],
    ) -> None:
        member = self.member
        assert isinstance(member, PairMember)
        for cob in sorted(member.cob_ids):
            install(cob, f"the pair's 0x{cob:03X}", self._peer_frame(self._on_pair_frame, cob))
        for p in self.nodes.values():
            for cob in p.node.outputs.cob_ids:
                if cob not in taken:  # an RPDO on its own TPDO's COB-ID: the TPDO is read
                    install(cob, f"{p.name} RPDO heard",
                            self._peer_frame(self._on_rpdo_heard, p, cob))  # fmt: skip
        if member.peer_node_id:
            install(COB_NMT_EC + member.peer_node_id, "the peer's heartbeat",
                    self._peer_frame(self._on_peer_heartbeat))  # fmt: skip

    @property
    def pair(self) -> FlyingMaster | None:
        """The role machine of this gateway in a pair (None outside a pair)."""
        return self.member.machine

    @property
    def role(self) -> str | None:
        """``active``, ``standby``, ``listening``, ``negotiating``, ``isolated``, ``duplicate``;
        None outside a pair."""
        return self.member.role

    @property
    def pair_master_id(self) -> int | None:
        """The pair id of the master heard active (this gateway's own while active; None:
        none heard within the take-over time, or outside a pair)."""
        machine = self.member.machine
        if machine is None:
            return None
        if machine.active:
            return machine.node_id
        claim = machine.peer
        heard = machine.active_heard_s
        if claim is None or heard is None or machine.role is not Role.STANDBY:
            return None
        return claim.node_id if self.clock() - heard <= machine.timing.takeover_s else None

    @property
    def pair_conflict(self) -> str | None:
        """What a device with this gateway's pair id was heard sending (None: nothing)."""
        return self.member.conflict

    @property
    def peer_heartbeat_s(self) -> float | None:
        """When the peer's own heartbeat was last heard (bus clock; None: not heard)."""
        return self.member.peer_heartbeat_s

    def _send_quiet(self, cob_id: int, data: bytes) -> None:
        try:
            self.driver.send(cob_id, data)
        except can.CanError:
            pass

    def _on_pair_frame(self, cob_id: int, data: bytes, wall: float, now: float) -> None:
        member = self.member
        assert isinstance(member, PairMember)
        met = member.machine.meetings
        learned = member.on_frame(cob_id, data, now)
        if member.machine.meetings != met and self.mastering:
            for p in self.nodes.values():  # another master: its nodes may run, none is probed
                listening.another_master(p.node, now)
        handlers = self.driver.handlers
        if learned is not None and self.peers.admit(learned):
            # the other gateway named its id in its claim: its own heartbeat is the peer's
            handlers[COB_NMT_EC + learned] = self._peer_frame(self._on_peer_heartbeat)
        third = member.watched_heartbeat()
        if third is not None and third not in handlers and self.peers.admit(third - COB_NMT_EC):
            # a third-party master is active: the standby watches its heartbeat
            handlers[third] = self._peer_frame(self._on_pair_frame, third)

    def _on_peer_heartbeat(self, data: bytes, wall: float, now: float) -> None:
        if isinstance(self.member, PairMember):
            self.member.on_peer_heartbeat(data, now)  # its role: a hand-over?

    def _on_rpdo_heard(
        self, p: NodeParts, cob_id: int, data: bytes, wall: float, now: float
    ) -> None:
        # another master's RPDO: the standby's outputs (mastering: an RPDO not known here)
        self._execute(p, p.node.on_rpdo_heard(cob_id, data, wall, now))

    def _role_changed(self, change: RoleChanged) -> None:
        now = self.clock()
        level = logging.WARNING if Role.ACTIVE in (change.role, change.previous) else logging.INFO
        log.log(level, "pair: %s -> %s (%s)", change.previous, change.role, change.reason)
        if change.role is Role.ACTIVE:
            self.mastering = True
            # the logical master's heartbeat at once: the devices' consumers go on
            self._send_quiet(COB_NMT_EC + self.cfg.master.node_id, MASTER_HEARTBEAT)
            for cob_id, frame, text in self.heard_sdo.abort_left_open():  # before any request
                self._send_quiet(cob_id, frame)
                log.info("%s", text)
            assert isinstance(self.member, PairMember)
            heard = self.member.machine.master_heard
            for p in self.nodes.values():
                self._execute(p, p.node.take_over(now, heard))
        elif change.previous is Role.ACTIVE or change.fresh:
            # back from its own outage (cut off, unable to send, stalled): a fresh joiner
            self.mastering = False
            if change.fresh:  # what it heard before the outage may have ended unheard
                self.heard_sdo.open.clear()
            for p in self.nodes.values():
                self._execute(p, p.node.stand_by(now, change.fresh))
            if change.previous is Role.ACTIVE:
                self._waiting.fail_all(NotActive(f"this gateway stood down ({change.role})"))
