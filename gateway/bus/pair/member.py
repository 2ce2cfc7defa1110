"""This gateway as a member of a hot-standby pair, as the master drives it.

It owns what the pair needs beside the nodes: the role machine (``flying_master.py``) fed with
the frames heard and the time, its timer on the event loop, the frames it asks for, and what a
standby learns that a take-over needs: an SDO transfer the other gateway left open (a request
heard without its answer) and the peer's id and own heartbeat. A role change goes to the master
(``on_role``), which owns the nodes and starts or stops mastering them.

Rule: everything runs on the event loop (the master hands it frames from its one inbox); it
does no blocking I/O; the master's ``send`` and ``clock`` are its only ways out and in.

Imports: bus.pair.flying_master, bus.sdo.client (the abort frame), cia301, config (types), asyncio (its timer), logging and the
standard library. Never a northbound module.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from gateway.bus.pair.flying_master import (
    FLYING_MASTER_COB_IDS,
    FlyingMaster,
    PairTiming,
    RoleChanged,
    Send,
)
from gateway.bus.sdo.client import abort_frame
from gateway.cia301 import COB_NMT_EC, COB_SDO_RX, SDO_ABORT_TIMEOUT
from gateway.config import Config

log = logging.getLogger("gateway.master")


def pair_timing(cfg: Config) -> PairTiming:
    """The times of the pair from ``master`` (``heartbeat_ms``) and ``master.redundancy``."""
    pair = cfg.master.redundancy
    assert pair is not None
    hb_s = cfg.master.heartbeat_ms / 1000.0
    takeover_s = pair.takeover_ms / 1000.0 if pair.takeover_ms else 3 * hb_s
    return PairTiming(
        takeover_s=takeover_s,
        detect_s=takeover_s,
        claim_period_s=hb_s,
        priority_slot_s=pair.priority_slot_ms / 1000.0,
        device_slot_s=pair.device_slot_ms / 1000.0,
    )


class PairMember:
    """The pair's side of the master (see the module docstring)."""

    def __init__(
        self,
        cfg: Config,
        send: Callable[[int, bytes], None],
        clock: Callable[[], float],
        on_role: Callable[[RoleChanged], None],
        before_poll: Callable[[], None] = lambda: None,
    ):
        pair = cfg.master.redundancy
        assert pair is not None
        self.machine = FlyingMaster(
            node_id=pair.node_id,
            priority=pair.priority,
            master_node_id=cfg.master.node_id,
            timing=pair_timing(cfg),
        )
        self.logical_heartbeat = COB_NMT_EC + cfg.master.node_id
        self.own_heartbeat = COB_NMT_EC + pair.node_id
        #: the other gateway's own id: configured, or learned from its claim (71h)
        self.peer_node_id: int | None = pair.peer_node_id
        #: when the peer's own heartbeat was last heard (bus clock)
        self.peer_heartbeat_s: float | None = None
        self._send, self._clock, self._on_role = send, clock, on_role
        #: called (role, reason) on the event loop after the master took a role change
        self.role_listeners: list[Callable[[str, str], None]] = []
        self._before_poll = before_poll  # the master drains what was heard before a timeout
        #: node id -> the first bytes of an SDO request the other gateway sent that no answer
        #: has followed yet (a transfer it may leave open)
        self._sdo_heard: dict[int, bytes] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        #: the loop's time when this member last ran: while active it runs every claim period,
        #: so a longer gap than the take-over time means the process did not run (``check``)
        self._ran_s: float | None = None

    # ------------------------------------------------------------------ queries
    @property
    def role(self) -> str:
        """``active``, ``standby``, ``listening``, ``negotiating``."""
        return str(self.machine.role)

    @property
    def cob_ids(self) -> frozenset[int]:
        """What the reader hands this member: the CiA 302-2 frames and the logical heartbeat."""
        return FLYING_MASTER_COB_IDS | {self.logical_heartbeat}

    def known_ids(self) -> set[int]:
        """The node ids of the pair's members (not unconfigured nodes that talk)."""
        own = self.own_heartbeat - COB_NMT_EC
        return {own} | ({self.peer_node_id} if self.peer_node_id else set())

    # ------------------------------------------------------------------ start / stop
    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._ran_s = loop.time()
        self._do(self.machine.start(self._clock()))

    def check(self) -> None:
        """Before this gateway acts on the bus (a node's timer, a producer): if it did not run
        for longer than the take-over time, the other gateway may be active now; an active one
        stands by first (``FlyingMaster.on_stall``)."""
        loop = self._loop
        if loop is None:
            return
        ran, self._ran_s = self._ran_s, loop.time()
        if ran is not None and self._ran_s - ran > self.machine.timing.takeover_s:
            log.warning("pair: this gateway did not run for %.1f s", self._ran_s - ran)
            self._do(self.machine.on_stall(self._clock()))

    def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._loop = None

    # ------------------------------------------------------------------ events (event loop)
    def on_frame(self, cob_id: int, data: bytes, now: float) -> int | None:
        """A frame of ``cob_ids``; returns the peer's id when this frame taught it."""
        self.check()
        self._do(self.machine.on_frame(cob_id, data, now))
        peer = self.machine.peer
        if peer is not None and self.peer_node_id is None:
            self.peer_node_id = peer.node_id
            return peer.node_id
        return None

    def on_peer_heartbeat(self, now: float) -> None:
        self.peer_heartbeat_s = now

    def on_sdo_request(self, node_id: int, data: bytes) -> None:
        """The other gateway's SDO request to a node (heard while standing by)."""
        self._sdo_heard[node_id] = bytes(data[:4])

    def on_sdo_response(self, node_id: int) -> None:
        self._sdo_heard.pop(node_id, None)  # answered: not left open by this frame

    def abort_left_open(self) -> None:
        """At a take-over: each SDO transfer the other gateway left open is aborted once."""
        heard, self._sdo_heard = self._sdo_heard, {}
        for node_id, head in heard.items():
            if len(head) < 4:
                continue
            index, sub = int.from_bytes(head[1:3], "little"), head[3]
            # SDO protocol timed out (CiA 301 7.2.4.3.17): the transfer's client is gone
            self._send(COB_SDO_RX + node_id, abort_frame(index, sub, SDO_ABORT_TIMEOUT))
            log.info("pair: SDO transfer left open on node id %d aborted", node_id)

    # ------------------------------------------------------------------ inside
    def _do(self, actions: list[Send | RoleChanged]) -> None:
        for a in actions:
            if isinstance(a, Send):
                self._send(a.cob_id, a.data)
                continue
            self._on_role(a)
            for listener in self.role_listeners:
                try:
                    listener(str(a.role), a.reason)
                except Exception:  # noqa: BLE001 - a listener must not stop the take-over
                    log.exception("role listener failed")
        self._schedule()

    def _schedule(self) -> None:
        loop = self._loop
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        deadline = self.machine.next_deadline_s()
        if loop is None or deadline is None:
            return
        # the machine's deadlines are on the bus clock, which may lag the loop's clock
        lag = max(0.0, loop.time() - self._clock())
        self._timer = loop.call_at(max(deadline + lag, loop.time()), self._tick)

    def _tick(self) -> None:
        self._timer = None
        self.check()
        self._before_poll()  # what was heard counts before a timeout
        self._do(self.machine.poll(self._clock()))
