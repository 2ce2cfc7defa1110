"""A simulated CANopen device (DS-301 slave) built from a device profile: sans-I/O.

``SimNode(profile, node_id)`` holds the object values of one device (EDS defaults, ``$NODEID``
resolved, overlaid with what 1010h stored) and reacts to frames and time:

- ``handle(msg, now)`` -> frames to send in answer to one received frame,
- ``tick(now)`` -> frames due at ``now`` (heartbeat, event-timer TPDOs, queued EMCY...).

``now`` is the caller's monotonic clock in seconds; the node never reads a clock, never sleeps
and never touches a bus, so tests drive it with a fake clock. What it implements, and where the
manuals say so (SGH10 manual 000/003 section numbers unless noted), and which module holds it:

- power-on, reset node, reset communication and the NMT commands (4.2.1, 4.2.2): ``nmt.py``
  says what a command asks and what a reset adopts and reloads; the node applies it (its NMT
  state and node id are its own). STOPPED answers only NMT, heartbeat, guarding.
- heartbeat producer 1017h (4.5.3), node guarding and life guarding (4.5.2):
  ``error_control.py``.
- SDO server (4.4.1, ``sdo.py``) in PRE-OPERATIONAL and OPERATIONAL, with the abort codes of
  4.4.1.3; what a read or write of an object checks and sets off (1003h, 1010h "save" / 1011h
  "load", the COB-ID rules of 1005h, 1014h and the PDOs, the profile's ranges):
  ``object_access.py``; the object values and the store: ``objects.py``.
- EMCY (4.5.1, ``emcy.py``), only in PRE-OPERATIONAL / OPERATIONAL, COB-ID from 1014h.
- TPDOs (4.3.1.1) from the current 180xh/1A0xh, only in OPERATIONAL: ``tpdo_producer.py``
  (event timer, SYNC, inhibit time); RTR on the TPDO COB-ID (bit 30 clear) here. RPDOs write
  their mapped objects. Mirrored objects (e.g. 180xh:05 with 6200h, 4.7.2.31) follow here.
- a motion model (``motion.py``) for the position / velocity objects named by the profile's
  ``sim:`` hints (or, for a device known only from its EDS, ``auto_inputs.py``), with the
  calibration: ``process.py``; the simulation of the profile's features (``features/``);
  injected faults (``device_faults.py``).

Each part owns its state and the node changes it only through the part's methods; a part sees
the node through a Protocol of what it uses (``ErrorControlHost``, ``TpdoHost``, ``ObjectHost``,
``FaultHost``) and never sets the node's fields.

Imports: python-can (Message only), canopen_gateway.canopen.cia301, canopen_gateway.canopen.states, canopen_gateway.profiles
(LoadedProfile, expected_identity), canopen_gateway.canopen.objref and the other canopen_gateway.sim modules. Nothing of
bus/, modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import can

import canopen_gateway.sim.nmt as nmt
import canopen_gateway.sim.object_access as object_access
import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.cia301 import (
    COB_ID_MASK_11BIT,
    COB_ID_NO_RTR,
    COB_NMT,
    COB_NMT_EC,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.profiles import LoadedProfile, expected_identity
from canopen_gateway.sim.auto_inputs import mapped_inputs
from canopen_gateway.sim.device_cob_ids import emcy_cob, receive_map, sdo_tx_cob
from canopen_gateway.sim.device_faults import DeviceFaults
from canopen_gateway.sim.emcy import EmcyProducer
from canopen_gateway.sim.error_control import ErrorControl
from canopen_gateway.sim.features import SimFeature, feature_class
from canopen_gateway.sim.hints import SimHints
from canopen_gateway.sim.motion import Motion, MotionConfig
from canopen_gateway.sim.objects import (
    ObjectValues,
    PersistentStore,
    decode,
    resolve_default,
)
from canopen_gateway.sim.process import ProcessModel
from canopen_gateway.sim.sdo import SdoServer
from canopen_gateway.sim.tpdo_producer import TpdoProducer

# Due times are sums of float periods (0.2 + 0.1 > 0.3): a timer is due within this margin.
_EPS_S = 1e-9


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
        self.pending_node_id: int | None = None  # adopted at the next reset (LSS, Auto-ID)
        self.store = store if store is not None else PersistentStore()
        raw: dict[str, Any] = {**profile.profile.sim, **(options or {})}
        if isinstance(motion, dict):
            raw["motion"] = {**(raw.get("motion") or {}), **motion}
        self.hints = SimHints.from_dict(raw, eds_only=not profile.profile.sim)
        # the identity the gateway checks (1018h), where the file gives it in [DeviceInfo] only
        self.values = ObjectValues(
            profile.od, {(o.index, o.sub): v for o, v in expected_identity(profile)}
        )
        self.nmt_state = NmtState.BOOTUP
        self.powered = False
        self.last_reset: nmt.ResetKind = "power"
        self.silenced = False
        self.mute_until_s: float | None = None  # off the bus for a while (LSS bit timing switch)
        self.now = 0.0
        self.rx_count = 0
        self.tx_count = 0
        self._out: list[can.Message] = []
        #: called when the frames the node acts on may have changed (see ``listening``)
        self.on_listening_changed: Callable[[], None] | None = None

        self.sdo = SdoServer(
            lambda index, sub: object_access.sdo_read(self, index, sub),
            lambda index, sub, data, size_given: object_access.sdo_write(
                self, index, sub, data, size_given
            ),
            timeout_s=self.hints.sdo_timeout_s,
            segment_upload_command=self.hints.segment_upload_command,
            expedited_only=self.hints.sdo_expedited_only,
        )
        self.emcy = EmcyProducer(self.values)
        self.mirror_groups: list[tuple[ObjRef, ...]] = []
        for group in self.hints.mirror_groups:
            present = tuple(o for o in group if self.values.has(*o))
            if len(present) > 1:
                self.mirror_groups.append(present)
        # a device known only from its EDS (no sim hints): its numeric TPDO-mapped inputs follow
        # the motion model, each offset by its position in the list
        auto_inputs: list[ObjRef] = []
        if self.hints.position is None and self.hints.velocity is None and not profile.profile.sim:
            auto_inputs = mapped_inputs(self.values, self.store, node_id)
        # motion model -> position / velocity objects
        self.motion = Motion(motion if isinstance(motion, MotionConfig) else self.hints.motion)
        self.process = ProcessModel(self.values, self.hints, self.motion, auto_inputs)
        self.tpdos = pdo.numbers(self.values, "tpdo")
        self.rpdos = pdo.numbers(self.values, "rpdo")
        self.tpdo_producer = TpdoProducer(self)
        self._cob_map: dict[int, tuple[str, int]] | None = None
        self.error_control = ErrorControl(self, emcy_codes=profile.profile.emcy)
        self.device_faults = DeviceFaults(self)

        self.features: list[SimFeature] = []
        feature_options = dict(raw.get("features") or {})
        for feature, params in profile.profile.features.items():
            cls = feature_class(feature)
            if cls is not None:
                merged = {**(params or {}), **feature_options.get(feature, {})}
                self.features.append(cls(self, merged))
        # after the features: a feature may add a mirror group (ds406_cycle_timer)
        self._mirrored = frozenset(o for group in self.mirror_groups for o in group)

    # ======================================================================================
    # API for features and tests
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

    def feature(self, feature: str) -> SimFeature | None:
        for b in self.features:
            if b.feature == feature:
                return b
        return None

    @property
    def position_offset(self) -> int:
        """Counts added to the model (calibration / preset; a referencing run sets it)."""
        return self.process.offset

    def adopt_node_id_at_reset(self, node_id: int) -> None:
        """The node id the next reset communication (or reset node) adopts (LSS, Auto-ID)."""
        self.pending_node_id = node_id

    def set_position_offset(self, counts: int) -> None:
        """A referencing run's calibration (its offset objects are the feature's)."""
        self.process.set_offset(counts, write_objects=False)

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
        for b in self.features:
            if b.on_frame(msg, now):
                return self.drain()
        if msg.is_extended_id or msg.is_error_frame:
            return self.drain()
        cob = msg.arbitration_id
        if cob == COB_NMT:
            if not msg.is_remote_frame and len(msg.data) >= 2:
                self._on_nmt_command(msg.data[0], msg.data[1], now)
            return self.drain()
        if cob == COB_NMT_EC + self.node_id and msg.is_remote_frame:
            self.error_control.on_guarding_rtr(now)
            return self.drain()
        if self.nmt_state == NmtState.STOPPED:
            return self.drain()
        target = self._cobs().get(cob)
        if target is not None:
            what, number = target
            if what == "sync" and not msg.is_remote_frame:
                for b in self.features:
                    b.on_sync(now)
                self.tpdo_producer.on_sync(now)
            elif what == "sdo" and not msg.is_remote_frame:
                response = self.sdo.on_request(bytes(msg.data), now)
                if response is not None:
                    self.send(sdo_tx_cob(self.node_id), response)
            elif self.nmt_state == NmtState.OPERATIONAL:
                if what == "tpdo" and msg.is_remote_frame and self.hints.tpdo_rtr:
                    if not pdo.cob_id(self.values, "tpdo", number) & COB_ID_NO_RTR:
                        self.tpdo_producer.send(number, now, force=True)
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
        for b in self.features:
            b.tick(now)
        if self._muted(now):
            self._out.clear()
            return []
        if self.nmt_state != NmtState.BOOTUP:
            self.error_control.tick(now)
        if self.nmt_state == NmtState.OPERATIONAL:
            self.tpdo_producer.tick(now)
        abort = self.sdo.poll(now)
        if abort is not None:
            self.send(sdo_tx_cob(self.node_id), abort)
        self._flush_emcy(now)
        return self.drain()

    def next_deadline(self, now: float) -> float | None:
        """Earliest time tick() has something to do (None: only on frames); a hint for
        drivers, tick() may still be called more often."""
        hb_next_s = self.error_control.hb_next_s
        due = [hb_next_s] if hb_next_s is not None else []
        if self.nmt_state == NmtState.OPERATIONAL:
            due += self.tpdo_producer.next_due()
        return min(due) if due else None

    def mute(self, until_s: float | None) -> None:
        """Stay off the bus until ``until_s`` (features still tick; None: back now)."""
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
        self.error_control.catch_up(now)
        self.tpdo_producer.catch_up(now)

    def stop_error_control(self) -> None:
        """Stop the heartbeat and the answers to node guarding; process data continue."""
        self.error_control.stop()

    def resume_error_control(self, now: float | None = None) -> None:
        """Heartbeat (next one now) and guarding answers again."""
        self.error_control.resume(self.now if now is None else now)

    def power_cycle(self, now: float | None = None) -> list[can.Message]:
        """Off and on again: stored configuration reloaded, boot-up sent."""
        now = self.now if now is None else now
        self.silenced = False
        self.error_control.resume(now)  # on again; the heartbeat rescheduled by the boot
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
        """Turn a device fault on/off; True if one of the node's features or the sim hint
        ``faults:`` implements it (``device_faults.py``)."""
        return self.device_faults.inject(name, active, self.now if now is None else now)

    def sensor_error(self, active: bool = True, now: float | None = None) -> bool:
        return self.inject_fault("sensor_error", active, now)

    def battery_low(self, active: bool = True, now: float | None = None) -> bool:
        return self.inject_fault("battery_low", active, now)

    def freeze_guarding_echo(self, active: bool = True, now: float | None = None) -> bool:
        return self.inject_fault("freeze_guarding_echo", active, now)

    # ======================================================================================
    # NMT (sim/nmt.py: initialisation and the NMT commands)
    # ======================================================================================
    def reset_communication(self, now: float) -> None:
        """As NMT 82h: adopt a pending node id and boot up again."""
        self._initialise("communication", now)

    def _initialise(self, kind: nmt.ResetKind, now: float) -> None:
        """INITIALISATION (SGH10 manual 4.2.1.1, ``nmt.py``), boot-up message, PRE-OPERATIONAL."""
        self.powered, self.last_reset, self.nmt_state = True, kind, NmtState.BOOTUP
        self.node_id = nmt.node_id_after_reset(
            kind, configured=self.configured_node_id, current=self.node_id,
            pending=self.pending_node_id, stored=self.store.node_id,
        )  # fmt: skip
        self.pending_node_id = None
        nmt.reload_objects(self.values, self.store, self.node_id, kind)
        if kind == "power":
            self.emcy.reset()
            self.device_faults.clear()
            self.process.power_on(now, self.store.position_offset)
        self.listening_changed()
        self.sdo.reset()
        self.error_control.reset()
        self.tpdo_producer.reset()
        self.process.invalidate()
        if kind != "power":  # the device still has its faults: show them again
            self.device_faults.show_again()
        for b in self.features:
            b.on_boot(now)
        self.send(COB_NMT_EC + self.node_id, b"\x00")  # boot-up (4.2.2), unless silenced
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self.error_control.schedule_heartbeat(now)
        for b in self.features:
            b.on_nmt(int(self.nmt_state), now)

    def _on_nmt_command(self, cs: int, target: int, now: float) -> None:
        """An NMT command ``[cs, target]`` (SGH10 manual 4.2.1): a reset or a new state."""
        asked = nmt.command(cs, target, self.node_id)
        if isinstance(asked, NmtState):
            self.set_nmt_state(asked, now)
        elif asked is not None:
            self._initialise(asked, now)

    def set_nmt_state(self, state: NmtState | int, now: float) -> None:
        """Enter ``state`` (features use this, e.g. external heartbeat -> PRE-OPERATIONAL)."""
        state = NmtState(state)
        if state == self.nmt_state:
            return
        old, self.nmt_state = self.nmt_state, state
        if state == NmtState.OPERATIONAL and old != NmtState.OPERATIONAL:
            self.tpdo_producer.enter_operational(now)
        if old == NmtState.OPERATIONAL:
            self.tpdo_producer.leave_operational()
        for b in self.features:
            b.on_nmt(int(state), now)

    @property
    def life_guarding_lost(self) -> bool:
        """No guarding RTR within 100Ch x 100Dh since the last one (SGH10 manual 4.5.2)."""
        return self.error_control.life_guarding_lost

    # ======================================================================================
    # EMCY
    # ======================================================================================
    def _emit_emcy(self, data: bytes, now: float) -> None:
        """EMCY only in OPERATIONAL / PRE-OPERATIONAL (SGH10 manual 4.5.1)."""
        if self.nmt_state not in (NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL):
            return
        self.emcy.queue(data)
        self._flush_emcy(now)

    def _flush_emcy(self, now: float) -> None:
        cob = emcy_cob(self.values, self.node_id)
        for data in self.emcy.poll(now):
            if cob is not None:
                self.send(cob, data)

    # ======================================================================================
    # Process data
    # ======================================================================================
    def invalidate_process(self) -> None:
        """The next update_process() recomputes even at the same ``now``."""
        self.process.invalidate()

    def update_process(self, now: float) -> None:
        """Motion model -> position/velocity objects, then the features' process update."""
        if self.process.sample(now):
            for b in self.features:
                b.update_process(now)

    def direction_sign(self) -> int:
        """-1 when the profile's direction bit is set (``ProcessModel.direction_sign``)."""
        return self.process.direction_sign()

    def calibrate(self, preset: int, now: float) -> None:
        """Make the position read ``preset`` now (``ProcessModel.calibrate``)."""
        self.process.calibrate(preset, now)

    def tpdo(self, number: int) -> pdo.TpdoParams:
        """TPDO ``number``'s current parameters and compiled mapping (cached until a PDO
        parameter object changes)."""
        return self.tpdo_producer.params(number)

    def tpdo_data(self, number: int, now: float) -> bytes:
        """The data TPDO ``number`` would carry now (current mapping)."""
        return self.tpdo_producer.data(number, now)

    def trigger_tpdo(self, number: int, now: float) -> None:
        """An application event for an event-driven TPDO (features), in OPERATIONAL only."""
        self.tpdo_producer.trigger(number, now)

    def _on_rpdo(self, number: int, data: bytes, now: float) -> None:
        entries = pdo.mapping(self.values, "rpdo", number)
        if len(data) < pdo.length_bytes(entries):
            if 0x8210 in self.profile.profile.emcy:  # DS-301: PDO not processed, length error
                self.raise_emcy(0x8210, 0x10, now=now)
            return
        for obj, value in pdo.unpack(self.values, entries, data):
            self.set(obj.index, obj.sub, value)
        for b in self.features:
            b.on_rpdo(number, data, now)

    # ======================================================================================
    # COB-ID dispatch (device_cob_ids.py)
    # ======================================================================================
    def listening(self) -> frozenset[int] | None:
        """The 11-bit COB-IDs of the frames ``handle`` acts on: NMT, its guarding RTR, SYNC,
        SDO, its PDOs and what the features look at. A runner may hand the node only those
        standard frames (every extended or error frame still goes to every node). None: every
        frame (not powered yet, or a feature that looks at all of them)."""
        if not self.powered:
            return None
        cobs = {COB_NMT, COB_NMT_EC + self.node_id, *self._cobs()}
        for b in self.features:
            ids = b.frame_cob_ids()
            if ids is None:
                return None
            cobs.update(ids)
        return frozenset(cobs)

    def listening_changed(self) -> None:
        """A COB-ID, PDO parameter or the node id may have changed: drop what was derived."""
        self._cob_map = None
        self.tpdo_producer.forget_params()
        if self.on_listening_changed is not None:
            self.on_listening_changed()

    def _cobs(self) -> dict[int, tuple[str, int]]:
        if self._cob_map is None:
            self._cob_map = receive_map(self.values, self.node_id, self.tpdos, self.rpdos)
        return self._cob_map

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
                self.listening_changed()
            if which is not None and which[0] == "tpdo" and not which[2] and o.sub == 5:
                self.tpdo_producer.event_timer_written(which[1])

    def default_of(self, index: int, sub: int = 0) -> Any:
        """EDS default of an object for the current node id."""
        return resolve_default(self.values.var(index, sub), self.node_id)

    def sdo_read_local(self, obj: ObjRef | str) -> Any:
        """Read as an SDO client would (hooks, process update); raises SdoAbortError."""
        o = ObjRef.parse(obj)
        var = self.values.var(o.index, o.sub)
        return decode(var, object_access.sdo_read(self, o.index, o.sub))
