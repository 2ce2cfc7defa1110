"""A CiA 302-2 flying master as other vendors' stacks ship it: the third-party master of the
pair's tests.

Written from the behaviour of a shipped implementation (emotas' ``co_flyingmaster.c``, as the
issue and the project's notes describe it), not from the gateway's own role machine, which it
must neither import nor mirror: it is the other side the pair has to get along with.

CiA 302-2 flying master frames (data ``[priority, node id]`` where a master names itself):

=====  ============================================================================
71h    the active master's claim / answer: ``[priority, node id]``
72h    start negotiation: every master-capable device starts its time slot
73h    which master is active? answered by the active master alone, with one 71h
74h    master-capable device present: ``[priority, node id]`` (the answer to 75h)
75h    detect master-capable devices: every one answers 74h
76h    force negotiation: the active master negotiates again
=====  ============================================================================

Timing (object 1F90h, defaults of the shipped stack): :01 master detect timeout 100 ms, :02
wait at start 500 ms, :03 priority, :04 priority time slot 1500 ms, :05 device time slot
10 ms, :06 multiple-master detect cycle 4000 ms.

States and transitions (``FlyingMaster302Machine``, driven by ``(event, now)``):

==========  ==============================  ==============================================
state       event                           action -> next state
==========  ==============================  ==============================================
waiting     1F90h:02 elapsed                send 73h -> detecting (1F90h:01)
detecting   71h of a better master          -> slave
detecting   71h of a worse master           send 76h + 72h -> negotiating
detecting   1F90h:01 elapsed                send 72h -> negotiating
negotiating slot elapsed                        send 71h + heartbeat -> active
negotiating 71h of a better master          -> slave
negotiating 71h of a worse master           (ignored: our own claim follows)
active      71h of a better master          -> slave
active      71h of a worse master           send 76h + 72h -> negotiating
active      73h                             send one 71h
active      76h                             -> negotiating (no frame)
active      heartbeat period elapsed        send heartbeat 700h + node id [05h]
active      1F90h:06 elapsed                send 76h (multiple-master detection)
slave       71h of a worse master           send 76h + 72h -> negotiating
any but     72h                             -> negotiating (slot from now)
waiting
any         75h                             send 74h
==========  ==============================  ==============================================

The slot is ``priority x 1F90h:04 + node id x 1F90h:05`` from the 72h (heard or sent); better
means a lower priority value, on equal priority a lower node id. A frame the machine sends is
not heard back by it (no echo on the bus).

``FlyingMaster302`` runs the machine on a python-can bus (e.g. a ``PairBus`` member) from its
own thread, waking only for a frame or its next deadline, and counts what it sent.

Imports: python-can and the standard library.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field

import can

ACTIVE_MASTER = 0x71  # claim / answer [priority, node id]
FORCE_NEGOTIATION_START = 0x72  # start of the time slots
DETECT_ACTIVE_MASTER = 0x73  # request: who is active?
MASTER_CAPABLE = 0x74  # answer to 75h [priority, node id]
DETECT_CAPABLE = 0x75  # request: every master-capable device answers 74h
FORCE_NEGOTIATION = 0x76  # the active master negotiates again
HEARTBEAT = 0x700
NMT_OPERATIONAL = 0x05

WAITING, DETECTING, NEGOTIATING, ACTIVE, SLAVE = (
    "waiting",
    "detecting",
    "negotiating",
    "active",
    "slave",
)


@dataclass(frozen=True)
class Timing302:
    """Object 1F90h of the flying master, in ms (CiA 302-2 defaults of the shipped stack)."""

    detect_timeout_ms: int = 100  # 1F90h:01
    start_delay_ms: int = 500  # 1F90h:02
    priority_slot_ms: int = 1500  # 1F90h:04
    node_slot_ms: int = 10  # 1F90h:05
    detect_cycle_ms: int = 4000  # 1F90h:06
    heartbeat_ms: int = 100  # its own heartbeat (1017h) while active


@dataclass
class FlyingMaster302Machine:
    """Sans-I/O: ``start(now)``, ``on_frame(cob_id, data, now)`` and ``on_time(now)`` return
    the frames to send as ``(cob_id, data)``; ``deadline`` is when it next needs ``on_time``."""

    node_id: int
    priority: int = 0
    timing: Timing302 = field(default_factory=Timing302)
    state: str = WAITING
    #: (priority, node id) of the master it takes for active (itself when active)
    active_master: tuple[int, int] | None = None
    #: transitions taken, in order: (from, to)
    history: list[tuple[str, str]] = field(default_factory=list)
    _state_deadline: float | None = None
    _heartbeat_at: float | None = None
    _detect_at: float | None = None

    @property
    def me(self) -> tuple[int, int]:
        return (self.priority, self.node_id)

    @property
    def slot_s(self) -> float:
        t = self.timing
        return (self.priority * t.priority_slot_ms + self.node_id * t.node_slot_ms) / 1000

    @property
    def deadline(self) -> float | None:
        times = [
            t for t in (self._state_deadline, self._heartbeat_at, self._detect_at) if t is not None
        ]
        return min(times) if times else None

    def _go(self, state: str, deadline: float | None = None) -> None:
        if state != self.state:
            self.history.append((self.state, state))
        self.state = state
        self._state_deadline = deadline
        if state != ACTIVE:
            self._heartbeat_at = self._detect_at = None

    def _claim(self) -> list[tuple[int, bytes]]:
        return [(ACTIVE_MASTER, bytes(self.me))]

    def _negotiate(self, now: float) -> None:
        self.active_master = None
        self._go(NEGOTIATING, now + self.slot_s)

    def _force(self, now: float) -> list[tuple[int, bytes]]:
        self._negotiate(now)
        return [(FORCE_NEGOTIATION, b""), (FORCE_NEGOTIATION_START, b"")]

    # ------------------------------------------------------------------ events
    def start(self, now: float) -> list[tuple[int, bytes]]:
        self._go(WAITING, now + self.timing.start_delay_ms / 1000)
        return []

    def on_time(self, now: float) -> list[tuple[int, bytes]]:
        out: list[tuple[int, bytes]] = []
        if self._state_deadline is not None and now >= self._state_deadline:
            if self.state == WAITING:
                self._go(DETECTING, now + self.timing.detect_timeout_ms / 1000)
                out.append((DETECT_ACTIVE_MASTER, b""))
            elif self.state == DETECTING:
                self._negotiate(now)
                out.append((FORCE_NEGOTIATION_START, b""))
            elif self.state == NEGOTIATING:
                self._go(ACTIVE)
                self.active_master = self.me
                out += self._claim()
                self._heartbeat_at = now  # sent just below
                self._detect_at = now + self.timing.detect_cycle_ms / 1000
        if self.state == ACTIVE:
            if self._heartbeat_at is not None and now >= self._heartbeat_at:
                out.append((HEARTBEAT + self.node_id, bytes([NMT_OPERATIONAL])))
                self._heartbeat_at = now + self.timing.heartbeat_ms / 1000
            if self._detect_at is not None and now >= self._detect_at:
                out.append((FORCE_NEGOTIATION, b""))
                self._detect_at = now + self.timing.detect_cycle_ms / 1000
        return out

    def on_frame(self, cob_id: int, data: bytes, now: float) -> list[tuple[int, bytes]]:
        if cob_id == DETECT_CAPABLE:
            return [(MASTER_CAPABLE, bytes(self.me))]
        if self.state == WAITING:
            return []
        if cob_id == FORCE_NEGOTIATION_START:
            self._negotiate(now)
            return []
        if cob_id == DETECT_ACTIVE_MASTER:
            return self._claim() if self.state == ACTIVE else []
        if cob_id == FORCE_NEGOTIATION:
            if self.state == ACTIVE:
                self._negotiate(now)
            return []
        if cob_id == ACTIVE_MASTER and len(data) >= 2:
            return self._on_claim((data[0], data[1]), now)
        return []

    def _on_claim(self, other: tuple[int, int], now: float) -> list[tuple[int, bytes]]:
        if other < self.me:  # a better master: lower priority value, then lower node id
            self._go(SLAVE)
            self.active_master = other
            return []
        if other == self.me or self.state == NEGOTIATING:
            return []  # our own claim ends the negotiation
        return self._force(now)


class FlyingMaster302:
    """The machine on a python-can bus, from its own thread; ``sent`` counts frames by COB-ID."""

    def __init__(
        self, bus: can.BusABC, node_id: int, priority: int = 0, timing: Timing302 | None = None
    ):
        self.bus = bus
        self.machine = FlyingMaster302Machine(node_id, priority, timing or Timing302())
        self.sent: collections.Counter[int] = collections.Counter()
        self.received: collections.Counter[int] = collections.Counter()
        self.errors: list[BaseException] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, name=f"flying-master-{node_id}", daemon=True
        )

    @property
    def state(self) -> str:
        return self.machine.state

    def start(self) -> FlyingMaster302:
        with self._lock:
            self._send(self.machine.start(time.monotonic()))
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def _send(self, frames: list[tuple[int, bytes]]) -> None:
        for cob_id, data in frames:
            self.bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))
            self.sent[cob_id] += 1

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                deadline = self.machine.deadline
                wait = 0.5 if deadline is None else max(0.0, deadline - time.monotonic())
                msg = self.bus.recv(timeout=min(wait, 0.5))
                now = time.monotonic()
                with self._lock:
                    if msg is not None and not msg.is_extended_id and not msg.is_error_frame:
                        self.received[msg.arbitration_id] += 1
                        self._send(self.machine.on_frame(msg.arbitration_id, bytes(msg.data), now))
                    self._send(self.machine.on_time(now))
        except BaseException as exc:  # noqa: BLE001 - a test reads it: no silent thread death
            self.errors.append(exc)
            raise
