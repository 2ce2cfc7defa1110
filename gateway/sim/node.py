"""A simulated CANopen device (DS-301 slave) built from a device profile: sans-I/O.

``SimNode(profile, node_id)`` holds the object values of one device (EDS defaults, ``$NODEID``
resolved, overlaid with what 1010h stored) and reacts to frames and time:

- ``handle(msg, now)`` -> frames to send in answer to one received frame,
- ``tick(now)`` -> frames due at ``now`` (heartbeat, event-timer TPDOs, queued EMCY...).

``now`` is the caller's monotonic clock in seconds; the node never reads a clock, never sleeps
and never touches a bus, so tests drive it with a fake clock. What it implements, and where the
manuals say so (SGH10 manual 000/003 section numbers unless noted):

- power-on (2.1, 4.2.2): boot-up 0x700+id data 00, then PRE-OPERATIONAL.
- NMT (4.2.1): COB 0x000 [cs, id], id 0 = all: 01 start, 02 stop, 80 pre-op, 81 reset node
  (reload every object from EDS default + store), 82 reset communication (reload 1000h-1FFFh,
  adopt a node id configured by LSS/Auto-ID). STOPPED answers only NMT, heartbeat, guarding.
- SDO server (4.4.1, see sdo.py) in PRE-OPERATIONAL and OPERATIONAL, with the abort codes of
  4.4.1.3; 1010h "save" / 1011h "load" (4.7.2.11/12) on sub-indices 1 (all), 2 (1000h-1FFFh),
  3 (6000h-9FFFh), 4 (2000h-5FFFh); wrong signature -> 0x08000020.
- COB-IDs (4.1): a valid PDO's COB-ID changes only after bit 31 was set -> else 0x08000022; and,
  with the sim hint ``cob_id_change_preop_only``, only in PRE-OPERATIONAL.
- heartbeat producer 1017h (4.5.3); node guarding (4.5.2): RTR on 0x700+id answered with
  toggle (0 first) | state; life guarding with 100Ch x 100Dh once the first RTR came.
- EMCY (4.5.1, see emcy.py), only in PRE-OPERATIONAL / OPERATIONAL, COB-ID from 1014h.
- TPDOs (4.3.1.1) from the current 180xh/1A0xh: types 254/255 on the event timer 180xh:05
  (mirrored with 6200h where the EDS has it, 4.7.2.31), 1..240 every n-th SYNC, 0 on SYNC when
  changed, RTR on the TPDO COB-ID (bit 30 clear); only in OPERATIONAL. RPDOs write their mapped
  objects.
- a motion model (motion.py) for the position / velocity objects named by the profile's
  ``sim:`` hints, and the behaviours of the profile's features (behaviours/).

Imports: python-can (Message only), gateway.cia301, gateway.states, gateway.profiles
(LoadedProfile), gateway.objref and the other gateway.sim modules. Nothing of bus/, modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import can

import gateway.sim.pdo as pdo
from gateway.cia301 import (
    BOOLEAN,
    COB_EMCY,
    COB_ID_INVALID,
    COB_ID_MASK_11BIT,
    COB_ID_MASK_29BIT,
    COB_ID_NO_RTR,
    COB_NMT,
    COB_NMT_EC,
    COB_SDO_RX,
    COB_SDO_TX,
    COB_SYNC,
    NMT_ENTER_PRE_OPERATIONAL,
    NMT_RESET_COMMUNICATION,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    NUMERIC_TYPES,
    REAL32,
    REAL64,
    SIGNED_TYPES,
    SYNC_GENERATOR,
    TYPE_BITS,
)
from gateway.objref import ObjRef
from gateway.profiles import LoadedProfile
from gateway.sim.behaviours import Behaviour, behaviour_for
from gateway.sim.emcy import EmcyProducer
from gateway.sim.hints import SimHints
from gateway.sim.motion import Motion, MotionConfig
from gateway.sim.objects import (
    ABORT_NO_DATA,
    ABORT_RANGE,
    ABORT_STATE,
    ABORT_STORE,
    ObjectValues,
    PersistentStore,
    SdoAbortError,
    decode,
    resolve_default,
)
from gateway.sim.sdo import SdoServer
from gateway.states import NmtState

# 1010h / 1011h signatures, ASCII "save" / "load" little-endian (SGH10 manual 4.7.2.11/12)
SIGNATURE_SAVE = 0x65766173
SIGNATURE_LOAD = 0x64616F6C


ResetKind = Literal["power", "node", "communication"]


#: numeric data types the default motion drives (REAL64 too: the simulator writes it)
_MOTION_TYPES = NUMERIC_TYPES | {REAL64}

# Due times are sums of float periods (0.2 + 0.1 > 0.3): a timer is due within this margin.
_EPS_S = 1e-9


@dataclass
class _TpdoTimer:
    next_due_s: float | None = None
    sync_count: int = 0
    last_data: bytes | None = None
    last_sent_s: float | None = None
    pending: bool = False  # held back by the inhibit time


class SimNode:
    """One simulated device. See the module docstring for what it implements."""

    def __init__(
        self,
        profile: LoadedProfile,
        node_id: int,
        *,
        motion: MotionConfig | dict[str, Any] | None = None,
        store: PersistentStore | None = None,
        options: dict[str, Any] | None = None,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} is not 1..127")
        self.profile = profile
        self.configured_node_id = node_id
        self.node_id = node_id
        self.pending_node_id: int | None = None
        self.store = store if store is not None else PersistentStore()
        raw: dict[str, Any] = {**profile.profile.sim, **(options or {})}
        if isinstance(motion, dict):
            raw["motion"] = {**(raw.get("motion") or {}), **motion}
        self.hints = SimHints.from_dict(raw)
        self.values = ObjectValues(profile.od)
        self.nmt_state = NmtState.BOOTUP
        self.powered = False
        self.silenced = False
        self.error_control_off = False  # heartbeat and guarding answers stopped (fault)
        self.mute_until_s: float | None = None  # off the bus for a while (LSS bit timing switch)
        self.last_reset: ResetKind = "power"
        self.now = 0.0
        self.faults: dict[str, bool] = {}
        self.rx_count = 0
        self.tx_count = 0
        self._out: list[can.Message] = []
        #: called when the frames the node acts on may have changed (see ``listening``)
        self.on_listening_changed: Callable[[], None] | None = None

        # motion model -> position / velocity objects
        self.motion = Motion(motion if isinstance(motion, MotionConfig) else self.hints.motion)
        self.position_obj = self.hints.position
        self.velocity_obj = self.hints.velocity
        self.velocity_scale = self.hints.velocity_scale
        self.position_offset = 0  # counts added to the model (calibration / preset)
        self._process_now: float | None = None

        self.sdo = SdoServer(
            self._sdo_read,
            self._sdo_write,
            timeout_s=float(raw.get("sdo_timeout_s", 1.0)),
            segment_upload_command=self.hints.segment_upload_command,
            expedited_only=self.hints.sdo_expedited_only,
        )
        self.emcy = EmcyProducer(self.values)
        self.mirror_groups: list[tuple[ObjRef, ...]] = []
        for group in self.hints.mirror_groups:
            present = tuple(o for o in group if self.values.has(*o))
            if len(present) > 1:
                self.mirror_groups.append(present)
        self.cob_id_change_preop_only = self.hints.cob_id_change_preop_only
        self.require_mappable = bool(raw.get("require_mappable", False))

        # a device known only from its EDS (no sim hints): its numeric TPDO-mapped inputs follow
        # the motion model, each offset by its position in the list
        # event-driven TPDOs without timer sent once on entering OPERATIONAL (sim option
        # tpdo_on_operational; default for devices known only from their EDS, as most do; the
        # manual devices keep what their manuals describe)
        self.tpdo_on_operational = bool(raw.get("tpdo_on_operational", not profile.profile.sim))
        self.auto_inputs: list[ObjRef] = []
        if self.position_obj is None and self.velocity_obj is None and not profile.profile.sim:
            self.auto_inputs = self._mapped_inputs(node_id)
        self.tpdos = pdo.numbers(self.values, "tpdo")
        self.rpdos = pdo.numbers(self.values, "rpdo")
        self._tpdo_timers: dict[int, _TpdoTimer] = {n: _TpdoTimer() for n in self.tpdos}
        self._cob_map: dict[int, tuple[str, int]] | None = None
        self._tpdo_params: dict[int, pdo.TpdoParams] = {}  # dropped when a PDO object changes

        self._hb_next_s: float | None = None
        self._guard_toggle = 0
        self._guard_last_rtr_s: float | None = None
        self.life_guarding_lost = False

        self.behaviours: list[Behaviour] = []
        feature_options = dict(raw.get("features") or {})
        for feature, params in profile.profile.features.items():
            cls = behaviour_for(feature)
            if cls is not None:
                merged = {**(params or {}), **feature_options.get(feature, {})}
                self.behaviours.append(cls(self, merged))
        # after the behaviours: a feature may add a mirror group (ds406_cycle_timer)
        self._mirrored = frozenset(o for group in self.mirror_groups for o in group)

    # ======================================================================================
    # API for behaviours and tests
    # ======================================================================================
    def get(self, index: int, sub: int = 0, default: Any = None) -> Any:
        """Current value of an object (no access check, no hooks)."""
        return self.values.get(index, sub, default)

    def set(self, index: int, sub: int, value: Any) -> None:
        """Set an object's value (no access check, no hooks); mirrored objects follow."""
        self.values.set(index, sub, value)
        self._after_value_change(ObjRef(index, sub), value)

    def send(self, cob_id: int, data: bytes = b"", *, rtr: bool = False, dlc: int = 0) -> None:
        """Queue a frame for the next return of handle()/tick() (dropped while silenced)."""
        if self.silenced:
            return
        self._out.append(
            can.Message(
                arbitration_id=cob_id,
                data=bytes(data),
                is_extended_id=cob_id > COB_ID_MASK_11BIT,
                is_remote_frame=rtr,
                dlc=dlc if rtr else len(data),
            )
        )

    def behaviour(self, feature: str) -> Behaviour | None:
        for b in self.behaviours:
            if b.feature == feature:
                return b
        return None

    def drain(self) -> list[can.Message]:
        """Frames queued outside handle()/tick() (fault injection between calls)."""
        out, self._out = self._out, []
        self.tx_count += len(out)
        return out

    # ======================================================================================
    # Driving the node
    # ======================================================================================
    def power_on(self, now: float) -> list[can.Message]:
        """Switch the device on (first call of handle()/tick() does it implicitly)."""
        self._initialise("power", now)
        return self.drain()

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        """Frames to send in answer to ``msg`` received at ``now``."""
        self.now = now
        if not self.powered:
            self._initialise("power", now)
        if self.silenced or self._muted(now):
            return []
        self.rx_count += 1
        for b in self.behaviours:
            if b.on_frame(msg, now):
                return self.drain()
        if msg.is_extended_id or msg.is_error_frame:
            return self.drain()
        cob = msg.arbitration_id
        if cob == COB_NMT:
            if not msg.is_remote_frame and len(msg.data) >= 2:
                self._on_nmt(msg.data[0], msg.data[1], now)
            return self.drain()
        if cob == COB_NMT_EC + self.node_id and msg.is_remote_frame:
            self._on_guarding_rtr(now)
            return self.drain()
        if self.nmt_state == NmtState.STOPPED:
            return self.drain()
        target = self._cobs().get(cob)
        if target is not None:
            what, number = target
            if what == "sync" and not msg.is_remote_frame:
                self._on_sync(now)
            elif what == "sdo" and not msg.is_remote_frame:
                response = self.sdo.on_request(bytes(msg.data), now)
                if response is not None:
                    self.send(self._sdo_tx_cob(), response)
            elif self.nmt_state == NmtState.OPERATIONAL:
                if what == "tpdo" and msg.is_remote_frame and self.hints.tpdo_rtr:
                    if not pdo.cob_id(self.values, "tpdo", number) & COB_ID_NO_RTR:
                        self._send_tpdo(number, now, force=True)
                elif what == "rpdo" and not msg.is_remote_frame:
                    self._on_rpdo(number, bytes(msg.data), now)
        return self.drain()

    def tick(self, now: float) -> list[can.Message]:
        """Frames due at ``now``."""
        self.now = now
        if not self.powered:
            self._initialise("power", now)
        if self.silenced:
            return []
        for b in self.behaviours:
            b.tick(now)
        if self._muted(now):
            self._out.clear()
            return []
        if self.nmt_state != NmtState.BOOTUP:
            self._tick_heartbeat(now)
            self._tick_life_guarding(now)
        if self.nmt_state == NmtState.OPERATIONAL:
            self._tick_tpdos(now)
        abort = self.sdo.poll(now)
        if abort is not None:
            self.send(self._sdo_tx_cob(), abort)
        self._flush_emcy(now)
        return self.drain()

    def next_deadline(self, now: float) -> float | None:
        """Earliest time tick() has something to do (None: only on frames); a hint for
        drivers, tick() may still be called more often."""
        due = [t for t in (self._hb_next_s,) if t is not None]
        if self.nmt_state == NmtState.OPERATIONAL:
            due += [t.next_due_s for t in self._tpdo_timers.values() if t.next_due_s is not None]
        return min(due) if due else None

    def mute(self, until_s: float | None) -> None:
        """Stay off the bus until ``until_s`` (behaviours still tick; None: back now)."""
        self.mute_until_s = until_s
        if until_s is not None:
            self._out.clear()

    def _muted(self, now: float) -> bool:
        if self.mute_until_s is None:
            return False
        if now + _EPS_S >= self.mute_until_s:
            self.mute_until_s = None
            return False
        return True

    # ======================================================================================
    # Fault injection (tests, demos, commissioning drills)
    # ======================================================================================
    def silence(self) -> None:
        """Leave the bus: receive nothing, send nothing (as with a cut cable)."""
        self.silenced = True
        self._out.clear()

    def unsilence(self, now: float | None = None) -> None:
        """Back on the bus in the same NMT state; timers continue from ``now``."""
        self.silenced = False
        now = self.now if now is None else now
        if self._hb_next_s is not None and self._hb_next_s < now:
            self._schedule_heartbeat(now)
        for t in self._tpdo_timers.values():
            if t.next_due_s is not None and t.next_due_s < now:
                t.next_due_s = now

    def stop_error_control(self) -> None:
        """Stop the heartbeat and the answers to node guarding; process data continue."""
        self.error_control_off = True

    def resume_error_control(self, now: float | None = None) -> None:
        """Heartbeat (next one now) and guarding answers again."""
        self.error_control_off = False
        if self._hb_next_s is not None:
            self._hb_next_s = self.now if now is None else now

    def power_cycle(self, now: float | None = None) -> list[can.Message]:
        """Off and on again: stored configuration reloaded, boot-up sent."""
        now = self.now if now is None else now
        self.silenced = False
        self.error_control_off = False
        self._initialise("power", now)
        return self.drain()

    def raise_emcy(
        self, code: int, register: int = 0, mfr: bytes = b"", now: float | None = None
    ) -> None:
        """Make an error active: 1001h, 1003h and one EMCY frame (if the state allows)."""
        data = self.emcy.raise_error(code, register, mfr)
        if data is not None:
            self._emit_emcy(data, self.now if now is None else now)

    def clear_emcy(self, code: int, now: float | None = None) -> None:
        """The error went away: EMCY 0000h with the remaining error register."""
        data = self.emcy.clear_error(code)
        if data is not None:
            self._emit_emcy(data, self.now if now is None else now)

    def inject_fault(self, name: str, active: bool, now: float | None = None) -> bool:
        """Turn a device fault on/off; True if one of the node's behaviours implements it.

        Without a behaviour, a fault listed in the sim hint ``faults: {name: {emcy: code,
        register: bits, alarm_bit: n}}`` raises / clears that EMCY and sets / clears bit n of
        the DS-406 alarms 6503h (default for ``sensor_error``: bit 0, position error,
        SGH10 manual 4.7.2.38).
        """
        now = self.now if now is None else now
        self.faults[name] = active
        handled = False
        for b in self.behaviours:
            handled = b.on_fault(name, active, now) or handled
        if not handled:
            spec = self.hints.faults.get(name)
            if spec and "emcy" in spec:
                self._hint_fault_bits(name, active)
                code = int(spec["emcy"])
                if active:
                    self.raise_emcy(code, int(spec.get("register", 0)), now=now)
                else:
                    self.clear_emcy(code, now=now)
                handled = True
        return handled

    def _hint_fault_bits(self, name: str, active: bool) -> None:
        spec = self.hints.faults.get(name) or {}
        alarm_bit = spec.get("alarm_bit", 0 if name == "sensor_error" else None)
        if alarm_bit is not None and self.values.has(0x6503, 0):
            alarms = int(self.values.get(0x6503, 0, 0))
            mask = 1 << int(alarm_bit)
            self.values.set(0x6503, 0, alarms | mask if active else alarms & ~mask)

    def sensor_error(self, active: bool = True, now: float | None = None) -> bool:
        return self.inject_fault("sensor_error", active, now)

    def battery_low(self, active: bool = True, now: float | None = None) -> bool:
        return self.inject_fault("battery_low", active, now)

    def freeze_guarding_echo(self, active: bool = True, now: float | None = None) -> bool:
        return self.inject_fault("freeze_guarding_echo", active, now)

    # ======================================================================================
    # Initialisation and NMT
    # ======================================================================================
    def _initialise(self, kind: ResetKind, now: float) -> None:
        """INITIALISATION (SGH10 manual 4.2.1.1), boot-up message, then PRE-OPERATIONAL."""
        self.powered = True
        self.last_reset = kind
        self.nmt_state = NmtState.BOOTUP
        if kind == "power":
            self.motion.start(now)
            self.node_id = self.store.node_id or self.configured_node_id
            self.pending_node_id = None
            self.values.load_defaults(self.node_id, self.store, 1)
            self.emcy.reset()
            self.faults.clear()
            self.position_offset = self.store.position_offset or 0
            if self.position_offset:
                for obj in self.hints.offset_objects:
                    if self.values.has(*obj):
                        self.values.set(*obj, -self.position_offset)
        else:
            if self.pending_node_id is not None:
                self.node_id = self.pending_node_id
                self.pending_node_id = None
            keep = {k: self.values.get(*k) for k in self.values.keys() if k[0] in (0x1001, 0x1003)}
            self.values.load_defaults(self.node_id, self.store, 1 if kind == "node" else 2)
            for k, v in keep.items():
                self.values.set(k[0], k[1], v)
        self._listening_changed()
        self.sdo.reset()
        self._guard_toggle = 0
        self._guard_last_rtr_s = None
        self.life_guarding_lost = False
        self._tpdo_timers = {n: _TpdoTimer() for n in self.tpdos}
        self._process_now = None
        if kind != "power":  # the device still has its faults: show them again
            for name, active in self.faults.items():
                if active:
                    self._hint_fault_bits(name, True)
        for b in self.behaviours:
            b.on_boot(now)
        self.send(COB_NMT_EC + self.node_id, b"\x00")  # boot-up (4.2.2), unless silenced
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self._schedule_heartbeat(now)
        for b in self.behaviours:
            b.on_nmt(int(self.nmt_state), now)

    def reset_communication(self, now: float) -> None:
        """As NMT 82h: adopt a pending node id and boot up again."""
        self._initialise("communication", now)

    def _on_nmt(self, cs: int, target: int, now: float) -> None:
        if target not in (0, self.node_id):
            return
        if cs == NMT_RESET_NODE:
            self._initialise("node", now)
            return
        if cs == NMT_RESET_COMMUNICATION:
            self._initialise("communication", now)
            return
        new = {
            NMT_START: NmtState.OPERATIONAL,
            NMT_STOP: NmtState.STOPPED,
            NMT_ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
        }.get(cs)
        if new is not None:
            self.set_nmt_state(new, now)

    def set_nmt_state(self, state: NmtState | int, now: float) -> None:
        """Enter ``state`` (behaviours use this, e.g. external heartbeat -> PRE-OPERATIONAL)."""
        state = NmtState(state)
        if state == self.nmt_state:
            return
        old = self.nmt_state
        self.nmt_state = state
        if state == NmtState.OPERATIONAL and old != NmtState.OPERATIONAL:
            for n, t in self._tpdo_timers.items():
                t.sync_count = 0
                t.last_data = None
                t.next_due_s = now if pdo.event_timer_ms(self.values, n) > 0 else None
                if (
                    self.tpdo_on_operational
                    and t.next_due_s is None
                    and pdo.transmission_type(self.values, "tpdo", n) >= 254
                ):
                    # an event-driven TPDO without timer is sent once on entering OPERATIONAL
                    # (its current values), then on events (CiA 301 7.3.2)
                    t.next_due_s = now
        if old == NmtState.OPERATIONAL:
            for t in self._tpdo_timers.values():
                t.next_due_s = None
        for b in self.behaviours:
            b.on_nmt(int(state), now)

    # ======================================================================================
    # Heartbeat and node guarding
    # ======================================================================================
    def _schedule_heartbeat(self, now: float) -> None:
        period_ms = int(self.values.get(0x1017, 0, 0))
        self._hb_next_s = now + period_ms / 1000 if period_ms > 0 else None

    def _tick_heartbeat(self, now: float) -> None:
        """Heartbeat producer 1017h (SGH10 manual 4.5.3): [state] every period, any state."""
        if self._hb_next_s is None or now + _EPS_S < self._hb_next_s or self.error_control_off:
            return
        period_s = int(self.values.get(0x1017, 0, 0)) / 1000
        self.send(COB_NMT_EC + self.node_id, bytes([int(self.nmt_state)]))
        if period_s <= 0:
            self._hb_next_s = None
            return
        self._hb_next_s += period_s
        if self._hb_next_s <= now:  # fell behind (e.g. a long pause): no burst
            self._hb_next_s = now + period_s

    def _on_guarding_rtr(self, now: float) -> None:
        """Node guarding (SGH10 manual 4.5.2): toggle bit 7 (0 first) | NMT state."""
        if int(self.values.get(0x1017, 0, 0)) and not self.hints.guarding_with_heartbeat:
            return  # DS-301 7.2.8.3: a node uses heartbeat or guarding, not both
        if self.error_control_off:
            return
        self.send(
            COB_NMT_EC + self.node_id, bytes([(self._guard_toggle << 7) | self.nmt_state])
        )
        self._guard_toggle ^= 1
        self._guard_last_rtr_s = now
        if self.life_guarding_lost:
            self.life_guarding_lost = False
            if self.emcy.active.get(0x8130) is not None:
                self.clear_emcy(0x8130, now)

    def _tick_life_guarding(self, now: float) -> None:
        """Life guarding: no RTR within 100Ch x 100Dh ms after the first one (4.5.2)."""
        if self._guard_last_rtr_s is None or self.life_guarding_lost:
            return
        guard_ms = int(self.values.get(0x100C, 0, 0))
        factor = int(self.values.get(0x100D, 0, 0))
        if guard_ms == 0 or factor == 0:
            return
        if now - self._guard_last_rtr_s > guard_ms * factor / 1000:
            self.life_guarding_lost = True
            if 0x8130 in self.profile.profile.emcy:  # only if the manual lists it
                self.raise_emcy(0x8130, 0x10, now=now)  # DS-301: life guard error, bit 4

    # ======================================================================================
    # EMCY
    # ======================================================================================
    def _emcy_cob(self) -> int | None:
        if not self.values.has(0x1014, 0):
            return COB_EMCY + self.node_id
        cob = int(self.values.get(0x1014, 0, 0))
        return None if cob & COB_ID_INVALID else cob & COB_ID_MASK_29BIT

    def _emit_emcy(self, data: bytes, now: float) -> None:
        """EMCY only in OPERATIONAL / PRE-OPERATIONAL (SGH10 manual 4.5.1)."""
        if self.nmt_state not in (NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL):
            return
        self.emcy.queue(data)
        self._flush_emcy(now)

    def _flush_emcy(self, now: float) -> None:
        cob = self._emcy_cob()
        for data in self.emcy.poll(now):
            if cob is not None:
                self.send(cob, data)

    # ======================================================================================
    # Process data
    # ======================================================================================
    def invalidate_process(self) -> None:
        """The next update_process() recomputes even at the same ``now``."""
        self._process_now = None

    def update_process(self, now: float) -> None:
        """Motion model -> position/velocity objects, then the behaviours' process update."""
        if self._process_now == now:
            return
        self._process_now = now
        pos, vel = self.motion.sample(now)
        for i, obj in enumerate(self.auto_inputs):
            self.values.set(*obj, self._auto_value(obj, pos + 7 * i))
        if self.position_obj is not None:
            self.values.set(*self.position_obj, self.position_from_model(pos))
        if self.velocity_obj is not None:
            self.values.set(*self.velocity_obj, int(round(vel * self.velocity_scale)))
        for b in self.behaviours:
            b.update_process(now)

    def _mapped_inputs(self, node_id: int) -> list[ObjRef]:
        """Numeric objects of the EDS's TPDO mappings (defaults, ``$NODEID`` resolved)."""
        self.values.load_defaults(node_id, self.store, 1)
        out: list[ObjRef] = []
        for n in pdo.numbers(self.values, "tpdo"):
            for e in pdo.mapping(self.values, "tpdo", n):
                obj = ObjRef(e.index, e.sub)
                var = self.values.vars.get((e.index, e.sub)) if e.index >= 0x1000 else None
                if var is None or obj in out or e.index < 0x2000:
                    continue
                if var.data_type in _MOTION_TYPES:
                    out.append(obj)
        return out

    def _auto_value(self, obj: ObjRef, model: float) -> Any:
        var = self.values.vars[(obj.index, obj.sub)]
        if var.data_type in (REAL32, REAL64):
            return round(model / 100.0, 3)
        bits = TYPE_BITS[var.data_type]
        if var.data_type == BOOLEAN:
            return int(model) // 1000 % 2
        signed = var.data_type in SIGNED_TYPES
        v = int(model) % (1 << bits) if bits < 32 else int(model)
        if signed and v >= 1 << (bits - 1):
            v -= 1 << bits
        return v

    # -- position model: direction x model + calibration offset + application offset ---------
    def direction_sign(self) -> int:
        """-1 when the profile's direction bit is set (e.g. 6000h bit 0, AP05 manual 5.7.2.49)."""
        d = self.hints.direction
        if d is None or not self.values.has(*d[0]):
            return 1
        return -1 if int(self.values.get(*d[0], 0)) >> d[1] & 1 else 1

    def position_from_model(self, model_counts: float) -> int:
        app = self.hints.application_offset
        app_offset = int(self.values.get(*app, 0)) if app is not None else 0
        return self.direction_sign() * int(round(model_counts)) + self.position_offset + app_offset

    def calibrate(self, preset: int, now: float) -> None:
        """Make the position read ``preset`` (+ the application offset) now: "Position value =
        0 + calibration value + offset value" (SGH10 manual 3.2, AP05 manual 4.4)."""
        model, _ = self.motion.sample(now)
        self.position_offset = int(preset) - self.direction_sign() * int(round(model))
        for obj in self.hints.offset_objects:
            if self.values.has(*obj):
                # SGH10 manual 4.7.2.44: 6509h = encoder value - position value
                self.values.set(*obj, -self.position_offset)
        self._process_now = None

    def _calibration_write(self, obj: ObjRef, value: Any, now: float) -> None:
        h = self.hints
        if h.calibration_trigger is None and obj == h.preset:
            self.calibrate(int(value), now)
        elif obj == h.calibration_trigger and int(value) == h.calibration_trigger_value:
            preset = int(self.values.get(*h.preset, 0)) if h.preset is not None else 0
            self.calibrate(preset, now)
            if h.calibration_done_value is not None:
                self.values.set(*obj, h.calibration_done_value)

    def tpdo(self, number: int) -> pdo.TpdoParams:
        """TPDO ``number``'s current parameters and compiled mapping (cached until a PDO
        parameter object changes)."""
        p = self._tpdo_params.get(number)
        if p is None:
            p = self._tpdo_params[number] = pdo.tpdo_params(self.values, number)
        return p

    def tpdo_data(self, number: int, now: float) -> bytes:
        """The data TPDO ``number`` would carry now (current mapping)."""
        self.update_process(now)
        data = pdo.pack_compiled(self.values, self.tpdo(number).plan)
        for b in self.behaviours:
            data = b.tpdo_data(number, data, now)
        return data

    def _send_tpdo(self, number: int, now: float, *, force: bool = False) -> bool:
        """Send TPDO ``number`` if it is valid (and the inhibit time allows unless forced)."""
        params = self.tpdo(number)
        cob = params.cob_id
        if cob & COB_ID_INVALID:
            return False
        t = self._tpdo_timers[number]
        inhibit_s = params.inhibit_s
        if not force and t.last_sent_s is not None and now < t.last_sent_s + inhibit_s:
            t.pending = True
            return False
        data = self.tpdo_data(number, now)
        self.send(cob & COB_ID_MASK_29BIT, data)
        t.last_data = data
        t.last_sent_s = now
        t.pending = False
        return True

    def trigger_tpdo(self, number: int, now: float) -> None:
        """An application event for an event-driven TPDO (behaviours), in OPERATIONAL only."""
        if self.nmt_state == NmtState.OPERATIONAL and number in self._tpdo_timers:
            if self.tpdo(number).transmission_type >= 254:
                self._send_tpdo(number, now)

    def _tick_tpdos(self, now: float) -> None:
        for n, t in self._tpdo_timers.items():
            if t.pending:
                self._send_tpdo(n, now)
            if t.next_due_s is None or now + _EPS_S < t.next_due_s:
                continue
            params = self.tpdo(n)
            period_s = params.event_timer_ms / 1000
            if params.transmission_type >= 254:
                self._send_tpdo(n, now)
            if period_s <= 0:
                t.next_due_s = None
                continue
            t.next_due_s += period_s
            if t.next_due_s <= now:
                t.next_due_s = now + period_s

    def _on_sync(self, now: float) -> None:
        """SYNC (SGH10 manual 4.2.3, 4.3.1.1): synchronous TPDOs in OPERATIONAL."""
        for b in self.behaviours:
            b.on_sync(now)
        if self.nmt_state != NmtState.OPERATIONAL:
            return
        for n, t in self._tpdo_timers.items():
            ttype = self.tpdo(n).transmission_type
            if ttype == 0:
                data = self.tpdo_data(n, now)
                if data != t.last_data:
                    self._send_tpdo(n, now, force=True)
            elif 1 <= ttype <= 240:
                t.sync_count += 1
                if t.sync_count >= ttype:
                    t.sync_count = 0
                    self._send_tpdo(n, now, force=True)

    def _on_rpdo(self, number: int, data: bytes, now: float) -> None:
        entries = pdo.mapping(self.values, "rpdo", number)
        if len(data) < pdo.length_bytes(entries):
            if 0x8210 in self.profile.profile.emcy:  # DS-301: PDO not processed, length error
                self.raise_emcy(0x8210, 0x10, now=now)
            return
        for obj, value in pdo.unpack(self.values, entries, data):
            self.set(obj.index, obj.sub, value)
        for b in self.behaviours:
            b.on_rpdo(number, data, now)

    # ======================================================================================
    # COB-ID dispatch
    # ======================================================================================
    def _sdo_rx_cob(self) -> int:
        v = self.values.get(0x1200, 1)
        return int(v) & COB_ID_MASK_11BIT if v is not None else COB_SDO_RX + self.node_id

    def _sdo_tx_cob(self) -> int:
        v = self.values.get(0x1200, 2)
        return int(v) & COB_ID_MASK_11BIT if v is not None else COB_SDO_TX + self.node_id

    def listening(self) -> frozenset[int] | None:
        """The 11-bit COB-IDs of the frames ``handle`` acts on: NMT, its guarding RTR, SYNC,
        SDO, its PDOs and what the behaviours look at. A runner may hand the node only those
        standard frames (every extended or error frame still goes to every node). None: every
        frame (not powered yet, or a behaviour that looks at all of them)."""
        if not self.powered:
            return None
        cobs = {COB_NMT, COB_NMT_EC + self.node_id, *self._cobs()}
        for b in self.behaviours:
            ids = b.frame_cob_ids()
            if ids is None:
                return None
            cobs.update(ids)
        return frozenset(cobs)

    def _listening_changed(self) -> None:
        """A COB-ID, PDO parameter or the node id may have changed: drop what was derived."""
        self._cob_map = None
        self._tpdo_params.clear()
        if self.on_listening_changed is not None:
            self.on_listening_changed()

    def _cobs(self) -> dict[int, tuple[str, int]]:
        if self._cob_map is None:
            m: dict[int, tuple[str, int]] = {}
            for n in self.tpdos:
                cob = pdo.cob_id(self.values, "tpdo", n)
                if not cob & COB_ID_INVALID:
                    m[cob & COB_ID_MASK_29BIT] = ("tpdo", n)
            for n in self.rpdos:
                cob = pdo.cob_id(self.values, "rpdo", n)
                if not cob & COB_ID_INVALID:
                    m[cob & COB_ID_MASK_29BIT] = ("rpdo", n)
            sync = self.values.get(0x1005, 0, COB_SYNC)
            m[int(sync) & COB_ID_MASK_11BIT] = ("sync", 0)
            m[self._sdo_rx_cob()] = ("sdo", 0)
            self._cob_map = m
        return self._cob_map

    # ======================================================================================
    # SDO server callbacks
    # ======================================================================================
    def _sdo_read(self, index: int, sub: int) -> bytes:
        now = self.now
        var = self.values.var(index, sub)  # 0x06020000 / 0x06090011 first
        obj = ObjRef(index, sub)
        if obj in self.hints.unused_objects:
            raise SdoAbortError(self.hints.unused_abort, f"{obj} is not used by this device")
        self.update_process(now)
        for b in self.behaviours:
            code = b.before_sdo_read(obj, now)
            if code is not None:
                raise SdoAbortError(code)
        if index == 0x1003 and sub > 0 and var.readable:
            if sub > int(self.values.get(0x1003, 0, 0)):
                raise SdoAbortError(ABORT_NO_DATA, f"1003h holds fewer than {sub} errors")
        return self.values.read_bytes(index, sub)

    def _sdo_write(self, index: int, sub: int, data: bytes, size_given: bool) -> None:
        now = self.now
        obj = ObjRef(index, sub)
        if obj in self.hints.unused_objects:
            self.values.var(index, sub)
            raise SdoAbortError(self.hints.unused_abort, f"{obj} is not used by this device")
        var, value = self.values.check_write(index, sub, data, size_given)
        self._check_profile_range(obj, value)
        for b in self.behaviours:
            code = b.before_sdo_write(obj, value, now)
            if code is not None:
                raise SdoAbortError(code)
        self._core_write(obj, value, now)
        for b in self.behaviours:
            b.after_sdo_write(obj, value, now)

    def _check_profile_range(self, obj: ObjRef, value: Any) -> None:
        sig = self.profile.profile.signal_for(obj)
        if sig is None or not isinstance(value, (int, float)):
            return
        if isinstance(value, int) and sig.type in ("int8", "int16", "int24", "int32", "int64"):
            bits = sig.bit_length  # an EDS UNSIGNED object the profile reads as signed
            if value >= 1 << (bits - 1):
                value -= 1 << bits
        eng = value * sig.scale + sig.offset  # profile min/max are engineering values
        tol = 1e-9 * max(1.0, abs(eng))
        if (sig.min is not None and eng < sig.min - tol) or (
            sig.max is not None and eng > sig.max + tol
        ):
            raise SdoAbortError(ABORT_RANGE, f"{obj} value {eng} outside {sig.min}..{sig.max}")

    def _check_preop(self, obj: ObjRef) -> None:
        if self.cob_id_change_preop_only and self.nmt_state != NmtState.PRE_OPERATIONAL:
            raise SdoAbortError(ABORT_STATE, f"{obj} is writable in PRE-OPERATIONAL only")

    def _core_write(self, obj: ObjRef, value: Any, now: float) -> None:
        """DS-301 objects with rules or side effects, then store the value."""
        index, sub = obj
        if index == 0x1003 and sub == 0:
            if value != 0:  # SGH10 manual 4.7.2.4: only 0 is written, clearing the list
                raise SdoAbortError(ABORT_RANGE, "1003h:00 accepts only 0")
            self.emcy.clear_history()
            return
        if index == 0x1010 and sub >= 1:
            if value != SIGNATURE_SAVE:
                raise SdoAbortError(ABORT_STORE, "1010h expects the signature 'save'")
            self.values.save(self.node_id, self.store, sub)
            if sub in (1, 3, 4):  # the calibration belongs to the application parameters
                self.store.position_offset = self.position_offset
            return
        if index == 0x1011 and sub >= 1:
            if value != SIGNATURE_LOAD:
                raise SdoAbortError(ABORT_STORE, "1011h expects the signature 'load'")
            self.values.restore(self.store, sub)
            if sub in (1, 3, 4):
                self.store.position_offset = None
            return
        if index in (0x1005, 0x1014):
            self._check_preop(obj)
            old = int(self.values.get(index, 0, 0))
            # 1005h: bit 30 set = this node generates SYNC; 1014h: bit 31 set = EMCY invalid
            guard_bit = SYNC_GENERATOR if index == 0x1005 else COB_ID_INVALID
            active = bool(old & guard_bit) if index == 0x1005 else not old & guard_bit
            if active and (old ^ int(value)) & COB_ID_MASK_29BIT:
                raise SdoAbortError(ABORT_STATE, f"{obj}: invalidate before changing the COB-ID")
        which = pdo.pdo_of(index)
        if which is not None:
            _, _, is_map = which
            if is_map or sub == 1:  # COB-ID and mapping (SGH10 manual 4.1, 4.2.1.1)
                self._check_preop(obj)
            pdo.check_write(self.values, index, sub, value, require_mappable=self.require_mappable)
        self.set(index, sub, value)
        if index == 0x1017:
            self._schedule_heartbeat(now)
        if obj in (self.hints.preset, self.hints.calibration_trigger):
            self._calibration_write(obj, value, now)
        if obj == self.hints.application_offset or (
            self.hints.direction is not None and obj == self.hints.direction[0]
        ):
            self._process_now = None

    def _after_value_change(self, obj: ObjRef, value: Any) -> None:
        index = obj.index
        if obj not in self._mirrored and not (0x1400 <= index < 0x1C00 or index in (0x1005, 0x1200)):
            return  # the common case (process objects): no mirror, no PDO parameter
        changed = [obj]
        for group in self.mirror_groups:
            if obj in group:
                for other in group:
                    if other != obj:
                        self.values.set(*other, value)
                        changed.append(other)
        for o in changed:
            which = pdo.pdo_of(o.index)
            if o.index in (0x1005, 0x1200) or which is not None:
                self._listening_changed()
            if which is not None and which[0] == "tpdo" and not which[2] and o.sub == 5:
                self._on_event_timer_written(which[1])

    def _on_event_timer_written(self, number: int) -> None:
        """SGH10 manual 4.7.2.17 180xh:05: a change applies with the next timer run; a timer
        started from 0 runs from now."""
        t = self._tpdo_timers.get(number)
        if t is None or self.nmt_state != NmtState.OPERATIONAL:
            return
        period_ms = pdo.event_timer_ms(self.values, number)
        if period_ms <= 0:
            t.next_due_s = None
        elif t.next_due_s is None:
            t.next_due_s = self.now + period_ms / 1000

    def default_of(self, index: int, sub: int = 0) -> Any:
        """EDS default of an object for the current node id."""
        return resolve_default(self.values.var(index, sub), self.node_id)

    def sdo_read_local(self, obj: ObjRef | str) -> Any:
        """Read as an SDO client would (hooks, process update); raises SdoAbortError."""
        o = ObjRef.parse(obj)
        return decode(self.values.var(o.index, o.sub), self._sdo_read(o.index, o.sub))
