"""This gateway as a member of a hot-standby pair, as the master drives it.

It owns what the pair needs beside the nodes: the role machine (``flying_master.py``) fed with
the frames heard, the link and the time; its own heartbeat (700h + its pair id, every
``heartbeat_ms``) on whose beat it also reports to the machine whether the bus is heard at all
(the time of the last frame the driver received, which its reader keeps anyway: no work
per frame) and checks
that this process ran on time; the role's timer on the event loop, re-armed only when the
deadline comes earlier (a later deadline is found when the timer fires, so a standby that hears
the logical heartbeat every period does not re-arm per frame); and the peer's own heartbeat. A
role change goes to the master (``on_role``), which owns the nodes and starts or stops mastering
them (and aborts the SDO transfers the other gateway left open: ``heard_sdo.py``).

Rule: everything runs on the event loop (the master hands it frames from its one inbox); it
does no blocking I/O; the master's ``send`` and ``clock`` are its only ways out and in.

Imports: bus.pair.flying_master, bus.producers (its heartbeat's schedule), canopen.cia301, config
(types), device.settings (types: how often the devices talk), asyncio (its timers), logging and
the standard library.
Never a northbound module.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable

from canopen_gateway.bus.pair.flying_master import (
    FLYING_MASTER_COB_IDS,
    FlyingMaster,
    Notice,
    PairTiming,
    Role,
    RoleChanged,
    Send,
)
from canopen_gateway.bus.producers import Periodic
from canopen_gateway.canopen.cia301 import COB_NMT_EC
from canopen_gateway.config import Config
from canopen_gateway.device.settings import NodeSettings

log = logging.getLogger("gateway.master")

#: a role deadline that comes while the reader is within a burst waits this long, this often
DEFER_S, DEFER_MAX = 0.005, 4
#: nothing heard of the peer this long (at least; 10 take-over times when longer): one warning
PEER_SILENT_S = 10.0


def talk_period_s(settings: Iterable[NodeSettings]) -> float | None:
    """The shortest period of a device that talks unasked (a heartbeat producer, 1017h): the
    longest the bus may be quiet while the master is alive (None: no device talks unasked)."""
    periods = [s.heartbeat_ms for s in settings if s.supervision == "heartbeat" and s.heartbeat_ms > 0]
    return min(periods) / 1000.0 if periods else None


def pair_timing(cfg: Config, talk_s: float | None = None) -> PairTiming:
    """The times of the pair from ``master`` (``heartbeat_ms``) and ``master.redundancy``;
    ``talk_s``: ``talk_period_s`` of the nodes."""
    pair = cfg.master.redundancy
    assert pair is not None
    hb_s = cfg.master.heartbeat_ms / 1000.0
    takeover_s = pair.takeover_ms / 1000.0 if pair.takeover_ms else 3 * hb_s
    return PairTiming(
        takeover_s=takeover_s,
        detect_s=takeover_s,
        detect_cycle_s=pair.detect_cycle_ms / 1000.0,
        heartbeat_s=hb_s,
        priority_slot_s=pair.priority_slot_ms / 1000.0,
        device_slot_s=pair.device_slot_ms / 1000.0,
        talk_s=talk_s,
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
        *,
        last_frame_s: Callable[[], float | None] = lambda: None,
        nodes_alive: Callable[[], bool] = lambda: False,
        reader_busy: Callable[[], bool] = lambda: False,
        talk_s: float | None = None,
    ):
        pair = cfg.master.redundancy
        assert pair is not None
        self.machine = FlyingMaster(
            node_id=pair.node_id,
            priority=pair.priority,
            master_node_id=cfg.master.node_id,
            timing=pair_timing(cfg, talk_s),
            echo=bool(cfg.can.bus_kwargs().get("receive_own_messages")),
            peer_id=pair.peer_node_id,
        )
        self.heartbeat_s = cfg.master.heartbeat_ms / 1000.0
        self.logical_heartbeat = COB_NMT_EC + cfg.master.node_id
        self.own_heartbeat = COB_NMT_EC + pair.node_id
        #: the other gateway's own id: configured, or learned from its claim (71h)
        self.peer_node_id: int | None = pair.peer_node_id
        #: when the peer's own heartbeat was last heard (bus clock)
        self.peer_heartbeat_s: float | None = None
        self._send, self._clock, self._on_role = send, clock, on_role
        self._last_frame_s, self._nodes_alive = last_frame_s, nodes_alive
        self._reader_busy = reader_busy  # the reader is within a burst: frames still to come
        self._deferred = 0
        #: called (role, reason) on the event loop after the master took a role change
        self.role_listeners: list[Callable[[str, str], None]] = []
        self._before_poll = before_poll  # the master drains what was heard before a timeout
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_at = 0.0
        self.rearms = 0  # the role timer armed (for the standby's cost)
        self._beat: Periodic | None = None
        self._beat_timer: asyncio.TimerHandle | None = None
        #: the loop's time when this member last ran: it runs every heartbeat period, so a
        #: longer gap than the take-over time means the process did not run (``check``)
        self._ran_s: float | None = None
        self._started_s = 0.0
        self._noticed: set[str] = set()  # notice keys logged in this role
        self.peer_silent = False  # the run-time warning: nothing heard of the peer for long

    # ------------------------------------------------------------------ queries
    @property
    def role(self) -> str:
        """``active``, ``standby``, ``listening``, ``negotiating``, ``isolated``, ``duplicate``."""
        return str(self.machine.role)

    @property
    def conflict(self) -> str | None:
        """What a device with this gateway's pair id was heard sending (None: nothing)."""
        return self.machine.conflict

    @property
    def cob_ids(self) -> frozenset[int]:
        """What the reader hands this member: the CiA 302-2 frames, the logical heartbeat and
        (without the echo) the heartbeat of this gateway's own pair id: another device's."""
        own = set() if self.machine.echo else {self.own_heartbeat}
        return FLYING_MASTER_COB_IDS | {self.logical_heartbeat} | own

    def watched_heartbeat(self) -> int | None:
        """The COB-ID of a third-party master's heartbeat the standby watches (None: none)."""
        third = self.machine.third_party
        return COB_NMT_EC + third.node_id if third is not None else None

    def known_ids(self) -> set[int]:
        """The node ids of the pair's members (not unconfigured nodes that talk)."""
        own = self.own_heartbeat - COB_NMT_EC
        return {own} | ({self.peer_node_id} if self.peer_node_id else set())

    # ------------------------------------------------------------------ start / stop
    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._ran_s = self._started_s = loop.time()
        # its own heartbeat from the second period on: a newcomer with the id of a member already
        # on the bus hears that member's heartbeat first, and stays out without disturbing it
        self._beat = Periodic(self.heartbeat_s, loop.time() + 2 * self.heartbeat_s)
        self._do(self.machine.start(self._clock()))
        self._on_beat()

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
        for t in (self._timer, self._beat_timer):
            if t is not None:
                t.cancel()
        self._timer = self._beat_timer = None
        self._loop = None

    # ------------------------------------------------------------------ events (event loop)
    def on_frame(self, cob_id: int, data: bytes, now: float) -> int | None:
        """A frame of ``cob_ids``; returns the peer's id when this frame taught it."""
        self.check()
        self._do(self.machine.on_frame(cob_id, data, now))
        peer = self.machine.peer
        if peer is not None and self.peer_node_id is None:
            self.peer_node_id = self.machine.peer_id = peer.node_id
            return peer.node_id
        return None

    def on_link(self, state: str) -> None:
        """The driver's bus state (its ``on_state``): ``down`` (closed, lost), ``error`` (its
        frames cannot go out: bus off, error passive, sends refused) or ``ok`` (not after
        ``stop``: a gateway that stops closes its bus)."""
        if self._loop is None:
            return
        self._do(self.machine.on_link(state != "down", self._clock(), sending=state == "ok"))

    def on_peer_heartbeat(self, data: bytes, now: float) -> None:
        """The other member's own heartbeat: its role (a hand-over when it stopped mastering)."""
        self.peer_heartbeat_s = now
        self._do(self.machine.on_peer_heartbeat(data, now))

    def hand_over(self) -> bool:
        """This gateway stops (SIGTERM): an active member whose peer stands by stops mastering
        and says so in its own heartbeat, sent at once: the standby takes the bus without a
        take-over time. True when it handed over."""
        if self._loop is None or self.machine.peer_role(self._clock()) != "standby":
            return False
        self._do(self.machine.hand_over(self._clock()))
        if self.machine.active:
            return False
        self._send(self.own_heartbeat, bytes((self.machine.own_state,)))
        return True

    # ------------------------------------------------------------------ inside
    def _on_beat(self) -> None:
        """Every heartbeat period: ran on time?, is the bus heard?, its own heartbeat."""
        loop, beat = self._loop, self._beat
        if loop is None or beat is None:
            return
        self.check()
        self._report_hearing()
        if beat.due(loop.time()) and self.machine.role is not Role.DUPLICATE:
            # its role in the state byte; isolated too: the peer finds it
            self._send(self.own_heartbeat, bytes((self.machine.own_state,)))
        self._watch_peer(loop.time())
        self._beat_timer = loop.call_at(beat.next_deadline(), self._on_beat)

    def _report_hearing(self) -> None:
        self._do(self.machine.on_hearing(self._clock(), self._last_frame_s(), self._nodes_alive()))

    def _watch_peer(self, now: float) -> None:
        """The run-time warning: nothing of the peer heard for long (two members each on a
        private bus, e.g. ``interface: virtual``, both active)."""
        limit = max(PEER_SILENT_S, 10 * self.machine.timing.takeover_s)
        claim = self.machine.peer
        heard = [t for t in (self.peer_heartbeat_s, claim.at_s if claim else None) if t is not None]
        last = max(heard) if heard else None
        silent = (self._clock() - last if last is not None else now - self._started_s) > limit
        if silent and not self.peer_silent:
            who = f"pair id {self.peer_node_id}" if self.peer_node_id else "another member"
            log.warning(
                "pair: nothing heard of the peer (%s) for %.0f s: it is stopped or cut off, or "
                "the two members are not on one bus (interface virtual is private to each "
                "process)", who, limit,
            )  # fmt: skip
        self.peer_silent = silent

    def _do(self, actions: list[Send | RoleChanged | Notice]) -> None:
        for a in actions:
            if isinstance(a, Send):
                self._send(a.cob_id, a.data)
            elif isinstance(a, Notice):
                if a.key not in self._noticed:
                    self._noticed.add(a.key)
                    log.warning("%s", a.text)
            else:
                self._noticed.clear()
                self._role_changed(a)
        self._schedule()

    def _role_changed(self, change: RoleChanged) -> None:
        self._on_role(change)
        for listener in self.role_listeners:
            try:
                listener(str(change.role), change.reason)
            except Exception:  # noqa: BLE001 - a listener must not stop the take-over
                log.exception("role listener failed")

    def _schedule(self) -> None:
        """Arm the role's timer when its deadline came earlier; a later one is found when the
        timer fires (``_tick`` polls, then arms for what is due next)."""
        loop = self._loop
        deadline = self.machine.next_deadline_s()
        if loop is None or deadline is None:
            return
        # the machine's deadlines are on the bus clock, which may lag the loop's clock
        lag = max(0.0, loop.time() - self._clock())
        at = max(deadline + lag, loop.time())
        if self._timer is not None:
            if self._timer_at <= at:
                return
            self._timer.cancel()
        self._timer, self._timer_at = loop.call_at(at, self._tick), at
        self.rearms += 1

    def _tick(self) -> None:
        self._timer = None
        loop = self._loop
        if loop is not None and self._reader_busy() and self._deferred < DEFER_MAX:
            # a burst is being read (e.g. after a relay's stall): what it brings counts before a
            # timeout is judged; a few milliseconds at most, so that a busy bus defers nothing
            self._deferred += 1
            self._timer, self._timer_at = loop.call_at(loop.time() + DEFER_S, self._tick), 0.0
            return
        self._deferred = 0
        self.check()
        self._before_poll()  # what was heard counts before a timeout
        self._report_hearing()
        self._do(self.machine.poll(self._clock()))
