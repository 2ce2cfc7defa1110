"""The simulated device's TPDO producer: when each TPDO goes out, and with which data.

``TpdoProducer(host)`` belongs to one ``SimNode`` (seen as ``TpdoHost``, a Protocol) and keeps,
per TPDO, its timer (next event time, SYNC count, last data, last send, a send held back by the
inhibit time) and its compiled parameters (from the current 180xh/1A0xh, dropped when a PDO
object changes). It implements (SGH10 manual 000/003 section numbers):

- transmission types 254/255 (4.3.1.1) on the event timer 180xh:05, with the inhibit time
  180xh:03; a timer written in OPERATIONAL applies with its next run, one started from 0 runs
  from now (4.7.2.17);
- types 1..240 every n-th SYNC, type 0 on SYNC when the data changed (4.2.3, 4.3.1.1);
- an application event (a feature's ``trigger_tpdo``) for an event-driven TPDO;
- with the sim option ``tpdo_on_operational``, an event-driven TPDO without timer sent once on
  entering OPERATIONAL (CiA 301 7.3.2);
- with the sim option ``tpdo_on_change``, an event-driven TPDO without timer (types 254/255,
  180xh:05 = 0) sent when its data change: the device samples its inputs every
  ``input_cycle_ms`` (from entering OPERATIONAL on) and sends each such TPDO whose data differ
  from what it last sent; no two frames of a TPDO closer than its inhibit time 180xh:03
  (100 us units, CiA 301 7.5.2.35), a change inside that window goes out when it ends.

A TPDO whose mapping has no entry is not sent (CiA 301 7.5.2.36: 00h disables the mapping).
TPDOs go out in OPERATIONAL only: the node calls ``enter_operational`` / ``leave_operational``
on its NMT changes. Sans-I/O as its node: it sends through ``host.send`` and reads no clock.

Imports: canopen_gateway.canopen.cia301 (COB-ID bits), canopen_gateway.canopen.states (NmtState), sim.pdo; sim.features,
sim.hints and sim.objects for types only. Nothing of bus/, modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.cia301 import COB_ID_INVALID, COB_ID_MASK_29BIT
from canopen_gateway.canopen.states import NmtState

if TYPE_CHECKING:
    from canopen_gateway.sim.features import SimFeature
    from canopen_gateway.sim.hints import SimHints
    from canopen_gateway.sim.objects import ObjectValues

# Due times are sums of float periods (0.2 + 0.1 > 0.3): a timer is due within this margin.
_EPS_S = 1e-9


@dataclass
class TpdoTimer:
    next_due_s: float | None = None
    sync_count: int = 0
    last_data: bytes | None = None
    last_sent_s: float | None = None
    pending: bool = False  # held back by the inhibit time


class TpdoHost(Protocol):
    """What the TPDO producer uses of its node (the sim hints hold its options)."""

    values: ObjectValues
    features: list[SimFeature]
    now: float
    tpdos: list[int]
    hints: SimHints
    nmt_state: NmtState

    def update_process(self, now: float) -> None: ...
    def send(self, cob_id: int, data: bytes = b"", *, rtr: bool = False, dlc: int = 0) -> None: ...


class TpdoProducer:
    """When the TPDOs of one simulated node are sent."""

    def __init__(self, node: TpdoHost) -> None:
        self.node = node
        self.timers: dict[int, TpdoTimer] = {n: TpdoTimer() for n in node.tpdos}
        self._params: dict[int, pdo.TpdoParams] = {}  # dropped when a PDO object changes
        #: next input sample of the change-driven TPDOs (None: not sampling)
        self.next_sample_s: float | None = None

    def reset(self) -> None:
        """Initialisation: every timer stopped, nothing sent yet."""
        self.timers = {n: TpdoTimer() for n in self.node.tpdos}
        self.next_sample_s = None

    def forget_params(self) -> None:
        """A PDO parameter or COB-ID may have changed."""
        self._params.clear()

    def params(self, number: int) -> pdo.TpdoParams:
        """TPDO ``number``'s current parameters and compiled mapping (cached)."""
        p = self._params.get(number)
        if p is None:
            p = self._params[number] = pdo.tpdo_params(self.node.values, number)
        return p

    def data(self, number: int, now: float) -> bytes:
        """The data TPDO ``number`` would carry now (current mapping)."""
        node = self.node
        node.update_process(now)
        data = pdo.pack_compiled(node.values, self.params(number).plan)
        for b in node.features:
            data = b.tpdo_data(number, data, now)
        return data

    def send(self, number: int, now: float, *, force: bool = False) -> bool:
        """Send TPDO ``number`` if it is valid (and the inhibit time allows unless forced)."""
        params = self.params(number)
        cob = params.cob_id
        if cob & COB_ID_INVALID:
            return False
        t = self.timers[number]
        inhibit_s = params.inhibit_s
        if not force and t.last_sent_s is not None and now + _EPS_S < t.last_sent_s + inhibit_s:
            t.pending = True
            return False
        data = self.data(number, now)
        if not params.plan and not data:
            return False  # CiA 301 7.5.2.36: 00h entries, the mapping is disabled: no PDO sent
        self.node.send(cob & COB_ID_MASK_29BIT, data)
        t.last_data = data
        t.last_sent_s = now
        t.pending = False
        return True

    def trigger(self, number: int, now: float) -> None:
        """An application event for an event-driven TPDO, in OPERATIONAL only."""
        if self.node.nmt_state == NmtState.OPERATIONAL and number in self.timers:
            if self.params(number).transmission_type >= 254:
                self.send(number, now)

    def next_due(self) -> list[float]:
        """The due times of the running event timers, of the next input sample and of the
        sends held back by the inhibit time."""
        due = [t.next_due_s for t in self.timers.values() if t.next_due_s is not None]
        if self.next_sample_s is not None:
            due.append(self.next_sample_s)
        for n, t in self.timers.items():
            if t.pending and t.last_sent_s is not None:
                due.append(t.last_sent_s + self.params(n).inhibit_s)
        return due

    def tick(self, now: float) -> None:
        for n, t in self.timers.items():
            if t.pending:
                self.send(n, now)
            if t.next_due_s is None or now + _EPS_S < t.next_due_s:
                continue
            params = self.params(n)
            period_s = params.event_timer_ms / 1000
            if params.transmission_type >= 254:
                self.send(n, now)
            if period_s <= 0:
                t.next_due_s = None
                continue
            t.next_due_s += period_s
            if t.next_due_s <= now:
                t.next_due_s = now + period_s
        if self.next_sample_s is not None and now + _EPS_S >= self.next_sample_s:
            self._send_changed(now)
            cycle_s = self.node.hints.input_cycle_s
            self.next_sample_s += cycle_s
            if self.next_sample_s <= now:
                self.next_sample_s = now + cycle_s

    def _send_changed(self, now: float) -> None:
        """An input sample: each valid change-driven TPDO whose data changed is sent (or held
        back by its inhibit time)."""
        for n, t in self.timers.items():
            params = self.params(n)
            if params.transmission_type < 254 or params.event_timer_ms or params.cob_id & COB_ID_INVALID:
                continue
            if self.data(n, now) != t.last_data:
                self.send(n, now)

    def on_sync(self, now: float) -> None:
        """SYNC (SGH10 manual 4.2.3, 4.3.1.1): synchronous TPDOs in OPERATIONAL."""
        if self.node.nmt_state != NmtState.OPERATIONAL:
            return
        for n, t in self.timers.items():
            ttype = self.params(n).transmission_type
            if ttype == 0:
                data = self.data(n, now)
                if data != t.last_data:
                    self.send(n, now, force=True)
            elif 1 <= ttype <= 240:
                t.sync_count += 1
                if t.sync_count >= ttype:
                    t.sync_count = 0
                    self.send(n, now, force=True)

    def enter_operational(self, now: float) -> None:
        """Start the event timers (and the once-on-start TPDOs)."""
        node = self.node
        for n, t in self.timers.items():
            t.sync_count = 0
            t.last_data = None
            t.next_due_s = now if pdo.event_timer_ms(node.values, n) > 0 else None
            if (
                node.hints.tpdo_on_operational
                and t.next_due_s is None
                and pdo.transmission_type(node.values, "tpdo", n) >= 254
            ):
                # an event-driven TPDO without timer is sent once on entering OPERATIONAL
                # (its current values), then on events (CiA 301 7.3.2)
                t.next_due_s = now
        self.next_sample_s = now if node.hints.tpdo_on_change else None

    def leave_operational(self) -> None:
        for t in self.timers.values():
            t.next_due_s = None
        self.next_sample_s = None

    def catch_up(self, now: float) -> None:
        """Back on the bus: timers that fell due meanwhile run from ``now``."""
        for t in self.timers.values():
            if t.next_due_s is not None and t.next_due_s < now:
                t.next_due_s = now
        if self.next_sample_s is not None and self.next_sample_s < now:
            self.next_sample_s = now

    def event_timer_written(self, number: int) -> None:
        """SGH10 manual 4.7.2.17 180xh:05: a change applies with the next timer run; a timer
        started from 0 runs from now."""
        t = self.timers.get(number)
        node = self.node
        if t is None or node.nmt_state != NmtState.OPERATIONAL:
            return
        period_ms = pdo.event_timer_ms(node.values, number)
        if period_ms <= 0:
            t.next_due_s = None
        elif t.next_due_s is None:
            t.next_due_s = node.now + period_ms / 1000
