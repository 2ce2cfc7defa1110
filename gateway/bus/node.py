"""One CANopen device as the master sees it: the single owner of the node's state.

Rule 1: everything the gateway decides about one node lives here, in ``Node``: its lifecycle
(boot-up, configuration, NMT start, probing), its supervision (heartbeat consumer or node
guarding, the guarding-bit check, the RPDO keep-alive that feeds an external heartbeat), its
SDO channel (one transfer at a time: boot steps, probes, value refreshes, commands), its output
image (the last values sent in each RPDO, bits included) and its health in the process image
(``NodeHealth``: only this class writes it).
Rule 2: no I/O and no clock. The driver (``bus.master``) feeds events with the time ``now``
(the bus clock: the time of the frames processed, seconds) — ``on_nmt_ec``, ``on_emcy``,
``on_echo``, ``on_sdo_response``, ``tick``, ``request_sdo``, ``write_outputs``, ``nmt`` — and
executes what they return: ``Send`` frames, ``SdoDone`` results, ``ValuesRead``,
``HealthChanged`` and ``Note`` (log lines). ``next_deadline()`` says when ``tick`` is next due;
the driver sleeps until the earliest deadline of all nodes.

The decisions are tables below: what the node-guarding master expects in each lifecycle state
(``GUARD_EXPECTS``), what an NMT command makes the node's expected state (``NMT_EXPECTS``), what
a finished SDO transfer means by its purpose (``Node._SDO_DONE``).

Truthfulness (docs/architecture.md, "Never lies"): a boot-up and a loss invalidate every value
of the node (``health.fresh_since = None``); values are good again only when received after the
gateway's NMT start (``fresh_since`` = that instant). TPDOs that send only on change are read
right after NMT start (RTR where the PDO allows it, else one SDO upload per mapped object).

Imports: bus.lifecycle, bus.supervision, bus.sdo_client, bus.emcy, bus.settings, bus.codec,
image, states, objref. Never python-can, asyncio, logging or a northbound module.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from gateway.bus.codec import RpdoCodec, TpdoCodec
from gateway.bus.emcy import EmcyHistory, decode_emcy
from gateway.bus.lifecycle import (
    BootTimeout,
    ConfigStep,
    Configured,
    LifecycleState,
    NodeLifecycle,
    SendNmt,
    StateChanged,
    StepFailed,
    StepSkipped,
    Wait,
    WriteStep,
    WrongDevice,
    decode_value,
)
from gateway.bus.sdo_client import SdoTransfer
from gateway.bus.settings import NodeSettings
from gateway.bus.supervision import (
    GuardingBitCheck,
    HeartbeatConsumer,
    InvalidStateByte,
    LinkFault,
    LinkOk,
    NodeGuardingMaster,
    NodeLost,
    SendGuardRtr,
    ToggleError,
    WrongState,
)
from gateway.errors import NodeNotOperational, Unmapped
from gateway.image import NodeHealth
from gateway.objref import ObjRef
from gateway.states import REPORTED_STATES, LinkState, NmtState

# --------------------------------------------------------------------------- outputs


@dataclass(frozen=True)
class Send:
    """Action: send this frame. ``rpdo`` marks process data sent (for the raw-PDO listeners)."""

    cob_id: int
    data: bytes = b""
    rtr: bool = False
    dlc: int | None = None
    rpdo: bool = False


@dataclass(frozen=True)
class SdoDone:
    """Result of a ``request_sdo``: ``data`` (upload bytes, b"" for a download) or an error."""

    token: int
    data: bytes | None
    abort_code: int | None = None
    timed_out: bool = False
    by_server: bool = False


@dataclass(frozen=True)
class ValuesRead:
    """Values read by SDO (refresh after NMT start): write them into the process image."""

    names: tuple[str, ...]
    values: tuple[Any, ...]


@dataclass(frozen=True)
class HealthChanged:
    what: str  # "state" | "emcy"


@dataclass(frozen=True)
class Note:
    """A line for the log (the driver writes it)."""

    level: int
    text: str
    kind: Any = None  # set: rate-limited per kind


Output = Send | SdoDone | ValuesRead | HealthChanged | Note

#: What a node-guarding answer must report in each lifecycle state (DS-301 node guarding: a
#: wrong state is an error). None = any valid state.
GUARD_EXPECTS: dict[LifecycleState, NmtState | None] = {
    LifecycleState.WAITING: None,  # not configured by us yet: whatever it reports
    LifecycleState.BOOTING: None,  # found running: NMT pre-operational is on its way
    LifecycleState.CONFIGURING: NmtState.PRE_OPERATIONAL,  # SGH10 manual 4.2.1.1
    LifecycleState.OPERATIONAL: NmtState.OPERATIONAL,  # after our NMT start
}

#: The state a node is meant to be in after an NMT command (None: it reboots, boot-up follows).
NMT_EXPECTS: dict[str, NmtState | None] = {
    "start": NmtState.OPERATIONAL,
    "stop": NmtState.STOPPED,
    "preop": NmtState.PRE_OPERATIONAL,
    "reset": None,
    "reset-comm": None,
}

OBJ_DEVICE_TYPE = ObjRef(0x1000, 0x00)


@dataclass
class _SdoJob:
    token: int
    obj: ObjRef
    data: bytes | None
    purpose: str  # "boot" | "probe" | "refresh" | "reference" | "user"
    arg: Any = None


@dataclass(frozen=True)
class Refresh:
    """How a change-only TPDO is read after NMT start: ``rtr`` or one SDO upload per object."""

    codec: TpdoCodec
    how: str  # "rtr" | "sdo"
    objects: tuple[tuple[str, ObjRef, str], ...] = ()  # (signal, object, type) for "sdo"


class Node:
    """The state of one node (see the module docstring)."""

    def __init__(
        self,
        name: str,
        node_id: int,
        settings: NodeSettings,
        health: NodeHealth,
        *,
        boot_steps: Sequence[ConfigStep] = (),
        configure: bool = True,
        tpdos: Sequence[TpdoCodec] = (),
        rpdos: Sequence[RpdoCodec] = (),
        refresh: Sequence[Refresh] = (),
        expected_device_type: int | None = None,
        emcy_texts: dict[int, str] | None = None,
        guard_names: tuple[str | None, str | None] = (None, None),
        referencing: dict[str, Any] | None = None,
        reference_signal: str | None = None,
        passive: bool = False,
    ):
        self.name = name
        self.node_id = node_id
        self.s = settings
        self.health = health
        self.passive = passive
        self.tpdos = list(tpdos)
        self.rpdos = list(rpdos)
        self.refresh_plan = list(refresh)
        self.emcy_texts = emcy_texts or {}
        self.boot_steps = tuple(boot_steps)
        self.lifecycle = NodeLifecycle(
            self.boot_steps if configure else [],
            boot_timeout_s=settings.boot_timeout_s,
            expected_device_type=expected_device_type,
        )
        grace = settings.boot_timeout_s if configure else None
        self.hb: HeartbeatConsumer | None = (
            HeartbeatConsumer(settings.heartbeat_ms, settings.heartbeat_multiple, grace)
            if settings.heartbeat_ms > 0 and settings.supervision == "heartbeat"
            else None
        )
        self.guard: NodeGuardingMaster | None = (
            NodeGuardingMaster(settings.guard_time_ms, settings.life_time_factor)
            if settings.supervision == "guarding"
            else None
        )
        gb = settings.guarding_bit
        self.gbit: GuardingBitCheck | None = (
            GuardingBitCheck(gb.tolerance_missed, gb.tolerance_ms / 1000.0) if gb else None
        )
        self.control_signal, self.status_signal = guard_names
        health.supervision = settings.supervision
        health.link = LinkState.UNKNOWN if self.gbit is not None else LinkState.NOT_USED
        self.emcy = EmcyHistory()
        self.referencing = referencing
        self.reference_signal = reference_signal
        # output image: per RPDO number, the values of its mapped fields in mapping order
        self.outputs: dict[int, list[Any]] = {r.number: r.initial_values() for r in self.rpdos}
        self.by_signal: dict[str, list[RpdoCodec]] = {}
        for r in self.rpdos:
            for n in r.names:
                self.by_signal.setdefault(n, []).append(r)
        self.last_rpdo_s: dict[int, float] = {}
        self.keepalive_s = settings.keepalive_ms / 1000.0
        # SDO channel
        self._jobs: deque[_SdoJob] = deque()
        self._active: tuple[_SdoJob, SdoTransfer] | None = None
        self._tokens = 0
        self.next_probe_s: float | None = None
        self._last_probe_end_s: float | None = None
        self._wait_until: float | None = None
        self._rtr_due_s: float | None = None

    # ================================================================== queries
    @property
    def alive(self) -> bool:
        return self.health.alive

    def next_deadline(self) -> float | None:
        times = [
            self.lifecycle.next_deadline(),
            self.hb.next_deadline() if self.hb else None,
            self.guard.next_deadline() if self.guard else None,
            self.gbit.next_deadline() if self.gbit else None,
            self._active[1].next_deadline() if self._active else None,
            self.next_probe_s if self.lifecycle.state is LifecycleState.WAITING else None,
            self._keepalive_due(),
            self._wait_until,
            self._rtr_due_s,
        ]
        if self.guard is not None and not self.guard.active and not self.passive:
            return 0.0  # the first poll activates guarding (its first RTR)
        return min((t for t in times if t is not None), default=None)

    def output(self, name: str, pdo: int | None = None) -> Any:
        """The last value sent for signal ``name`` (in RPDO ``pdo``, default: the last one)."""
        codecs = self.by_signal.get(name)
        if not codecs:
            raise Unmapped(f"node {self.name}: {name} is not in an RPDO")
        codec = next((c for c in codecs if c.number == pdo), codecs[-1])
        idx = codec.index_of(name)
        assert idx is not None
        return self.outputs[codec.number][idx]

    def sdo_busy(self) -> bool:
        """A transfer is running or waiting."""
        return self._active is not None or bool(self._jobs)

    def is_output(self, name: str) -> bool:
        return name in self.by_signal

    # ================================================================== events
    def start(self, now: float, probe: bool = True) -> list[Output]:
        self.lifecycle.start(now)
        self.health.lifecycle = str(self.lifecycle.state)
        if self.passive:
            return []
        self.next_probe_s = now if probe else now + self.s.probe_period_s
        return self.tick(now)

    def tick(self, now: float) -> list[Output]:
        """Time has passed: timeouts, retries, scheduled frames."""
        out: list[Output] = []
        if self._active is not None:
            job, tr = self._active
            out += self._sdo_frames(tr.poll(now))
            if tr.done:
                out += self._sdo_finished(now)
        if self.guard is not None and not self.passive:
            for o in self.guard.poll(now):
                if isinstance(o, SendGuardRtr):
                    out.append(Send(0x700 + self.node_id, b"", rtr=True, dlc=1))
                elif isinstance(o, NodeLost):
                    out += self._lost(now, o.reason)
        if self.hb is not None:
            for o in self.hb.poll(now):
                if isinstance(o, NodeLost):
                    out += self._lost(now, o.reason)
        out += self._lifecycle_changes(self.lifecycle.poll(now), now)
        if self.gbit is not None:
            out += self._link(self.gbit.poll(now))
        if self._wait_until is not None and now >= self._wait_until:
            self._wait_until = None
        due = self._keepalive_due()
        if due is not None and now >= due:
            out += self._keepalive(now)
        if self._rtr_due_s is not None and now >= self._rtr_due_s:
            out += self._rtr_poll(now)
        if (
            self.lifecycle.state is LifecycleState.WAITING
            and self.next_probe_s is not None
            and now >= self.next_probe_s
        ):
            out += self._probe(now)
        out += self._drive(now)
        return out

    def on_nmt_ec(self, byte: int, now: float) -> list[Output]:
        """A frame on 700h + node id: boot-up (00h), heartbeat, or node-guarding answer."""
        if byte == NmtState.BOOTUP:
            return self._bootup(now)
        if self.guard is not None:
            outs = self.guard.on_response(byte, now)
            state = byte & 0x7F
        elif self.hb is not None:
            outs = self.hb.on_heartbeat(byte, now)
            state = byte & 0x7F
        else:
            outs, state = [], byte & 0x7F
        out: list[Output] = []
        bad = [o for o in outs if isinstance(o, (ToggleError, WrongState, InvalidStateByte))]
        for o in bad:
            out.append(Note(logging.WARNING, f"node {self.name}: {o}", ("guard", self.name, type(o).__name__)))
        if bad or state not in REPORTED_STATES:
            return out
        out += self._set_nmt(NmtState(state))
        sup = self.guard or self.hb
        if sup is None or sup.alive:
            out += self._set_alive(True, now)
        if self.lifecycle.state is LifecycleState.WAITING and not self.passive:
            # alive but no boot-up seen (gateway restarted, node replugged): probe soon
            if self._probe_in_flight() is None and (
                self._last_probe_end_s is None or now - self._last_probe_end_s >= min(1.0, self.s.probe_period_s)
            ):
                out += self._probe(now)
                out += self._drive(now)
        return out

    def on_emcy(self, data: bytes, wall_ts: float, now: float) -> list[Output]:
        h = self.health
        if len(data) < 3:
            h.emcy_errors += 1
            return [Note(logging.WARNING, f"node {self.name}: EMCY with {len(data)} bytes ignored", ("emcy_short", self.name))]
        rec = decode_emcy(bytes(data), self.emcy_texts, wall_ts)
        self.emcy.add(rec)
        h.last_emcy = rec  # type: ignore[assignment]
        h.emcy_count += 1
        h.emcy_history = tuple(self.emcy.history)
        h.current_errors = sorted(self.emcy.current)
        out: list[Output] = [
            Note(logging.WARNING, f"node {self.name} EMCY 0x{rec.code:04X} ({rec.text}) register 0x{rec.register:02X}"),
            HealthChanged("emcy"),
        ]
        if self.referencing is not None and not self.passive:
            out += self._check_reference(now)
        return out

    def on_echo(self, bit: int, now: float) -> list[Output]:
        """The guarding bit of a status word just received in a TPDO (AP05 manual 5.5.5)."""
        if self.gbit is None:
            return []
        return self._link(self.gbit.on_status(bit, now))

    def on_sdo_response(self, data: bytes, now: float) -> list[Output]:
        if self._active is None:
            return []
        _job, tr = self._active
        out = self._sdo_frames(tr.on_response(data, now))
        if tr.done:
            out += self._sdo_finished(now)
        if self.guard is not None and self.lifecycle.state in (LifecycleState.BOOTING, LifecycleState.CONFIGURING):
            self.guard.on_sign_of_life(now)  # a node answering its configuration is not lost
        return out

    def on_bus_down(self, now: float) -> list[Output]:
        """The bus is down: the node's state is not known any more."""
        return self._set_nmt(NmtState.UNKNOWN)

    def request_sdo(self, obj: ObjRef, data: bytes | None, now: float, purpose: str = "user", arg: Any = None) -> tuple[int, list[Output]]:
        """Queue an SDO upload (``data`` None) or download; ``SdoDone(token)`` reports it."""
        self._tokens += 1
        token = self._tokens
        self._jobs.append(_SdoJob(token, obj, data, purpose, arg))
        return token, self._drive(now)

    def on_nmt_command(self, command: str) -> None:
        """An NMT command a client sent to this node: the state guarding expects follows it."""
        if self.guard is not None:
            self.guard.expect(NMT_EXPECTS[command])

    def write_outputs(self, per_pdo: dict[int | None, dict[str, Any]], now: float, send: Sequence[int] | None = None) -> list[Output]:
        """Set output values and send the RPDOs that carry them (one frame per RPDO).

        ``per_pdo[None]`` applies to every RPDO mapping the signal, ``per_pdo[n]`` to RPDO n
        only. Which RPDOs go out (unless ``send`` says): those carrying a signal mapped only
        there; a signal mapped in several RPDOs (a shared control word) alone goes out in the
        last of them. Raises NodeNotOperational (nothing changed) when the node is not
        operational."""
        self.require_operational()
        names = [n for vals in per_pdo.values() for n in vals]
        for n in names:
            if n not in self.by_signal:
                raise Unmapped(f"node {self.name}: {n} is not in an RPDO")
        numbers: list[int] = list(send or [])
        if not numbers:
            for pdo, vals in per_pdo.items():
                for n in vals:
                    cs = self.by_signal[n]
                    if pdo is not None:
                        numbers.append(pdo)
                    elif len(cs) == 1:
                        numbers.append(cs[0].number)
            if not numbers:
                numbers.append(self.by_signal[names[0]][-1].number)
        for pdo, vals in per_pdo.items():
            for n, v in vals.items():
                for c in self.by_signal[n]:
                    if pdo is None or c.number == pdo:
                        self.outputs[c.number][c.index_of(n)] = v  # type: ignore[index]
        out: list[Output] = []
        for number in sorted(set(numbers)):
            out += self._send_rpdo(number, now)
        return out

    def require_operational(self) -> None:
        h = self.health
        if not h.alive:
            raise NodeNotOperational(self.name, "not alive (lost or never booted)")
        if h.nmt_state != NmtState.OPERATIONAL:
            raise NodeNotOperational(self.name, f"NMT state {h.nmt_state.name}")

    # ================================================================== internals: lifecycle
    def _bootup(self, now: float) -> list[Output]:
        h = self.health
        h.boot_count += 1
        out: list[Output] = [Note(logging.INFO, f"node {self.name} (id {self.node_id}) boot-up")]
        self._invalidate()
        if self.hb is not None:
            self.hb.on_bootup(now)
        if self.guard is not None:
            self.guard.on_bootup(now)  # the toggle bit starts at 0 again (DS-301)
        if self.gbit is not None:
            self.gbit.reset()
            out += self._set_link(LinkState.UNKNOWN)
        self.emcy.clear()
        h.current_errors = []
        out += self._set_referenced(False)  # MSK5000 5115h: the reference is lost at power-on
        out += self._set_nmt(NmtState.PRE_OPERATIONAL)
        out += self._set_alive(True, now)
        # a boot-up ends whatever transfer was running: the device forgot it
        out += self._cancel_active(now, "the node rebooted during the transfer")
        self._jobs = deque(j for j in self._jobs if j.purpose == "user")
        if self.passive:
            return out
        out += self._lifecycle_changes(self.lifecycle.on_bootup(now), now)
        out += self._drive(now)
        return out

    def _lost(self, now: float, reason: str) -> list[Output]:
        if not self.health.alive:
            return []
        out = self._set_alive(False, now, reason)
        return out

    def _set_alive(self, alive: bool, now: float, reason: str = "") -> list[Output]:
        h = self.health
        if h.alive == alive:
            return []
        h.alive = alive
        out: list[Output] = []
        if not alive:
            h.loss_count += 1
            self._invalidate()
            out += self._set_nmt(NmtState.UNKNOWN)
            if self.gbit is not None:
                self.gbit.reset()
                out += self._set_link(LinkState.UNKNOWN)
            out.append(Note(logging.WARNING, f"node {self.name} (id {self.node_id}) lost ({reason or self.s.supervision})"))
            if not self.passive:
                out += self._lifecycle_changes(self.lifecycle.on_lost(now), now)
                self.next_probe_s = now + self.s.probe_period_s  # cadence counted from the loss
        else:
            out.append(Note(logging.INFO, f"node {self.name} (id {self.node_id}) alive"))
        out.append(HealthChanged("state"))
        return out

    def _invalidate(self) -> None:
        self.health.fresh_since = None
        self._rtr_due_s = None

    def _lifecycle_changes(self, changes: list[Any], now: float) -> list[Output]:
        h = self.health
        out: list[Output] = []
        for ch in changes:
            if isinstance(ch, StateChanged):
                h.lifecycle = str(ch.new)
                out.append(Note(logging.INFO, f"node {self.name}: {ch.old} -> {ch.new} ({ch.reason})"))
                if self.guard is not None:
                    self.guard.expect(GUARD_EXPECTS[ch.new])
            elif isinstance(ch, StepFailed):
                h.last_error = ch.message
                if ch.abort_code is not None:
                    h.last_sdo_abort = ch.abort_code
                self._wait_until = now + ch.retry_in_s
                out.append(Note(logging.WARNING, f"node {self.name}: boot step {ch.index} failed: {ch.message}; retry {ch.attempt} in {ch.retry_in_s:.1f} s"))
            elif isinstance(ch, StepSkipped):
                out.append(Note(logging.INFO, f"node {self.name}: optional boot step skipped: {ch.message}"))
            elif isinstance(ch, BootTimeout):
                h.last_error = self.lifecycle.last_error or "no boot-up"
                out.append(Note(logging.WARNING, f"node {self.name} (id {self.node_id}): {h.last_error}"))
            elif isinstance(ch, WrongDevice):
                h.last_error = self.lifecycle.last_error or "wrong device type"
                out.append(Note(logging.ERROR, f"node {self.name} (id {self.node_id}): {h.last_error}"))
            elif isinstance(ch, Configured):
                h.last_error = ""
                h.fresh_since = now  # values are good again when received from now on
                out.append(Note(logging.INFO, f"node {self.name} (id {self.node_id}) configured in {ch.duration_s * 1000:.0f} ms and started"))
                out += self._set_nmt_expected(NmtState.OPERATIONAL)
                out += self._refresh(now)
                if self.referencing is not None:
                    out += self._check_reference(now)
                if self.s.rtr_poll_ms:
                    self._rtr_due_s = now + self.s.rtr_poll_ms / 1000.0
        if changes:
            out.append(HealthChanged("state"))
        return out

    def _set_nmt_expected(self, state: NmtState) -> list[Output]:
        """After our NMT start the node is operational (its next heartbeat confirms it)."""
        if self.hb is None and self.guard is None:
            return self._set_nmt(state)
        return []

    def _drive(self, now: float) -> list[Output]:
        """Start the next SDO transfer / NMT command when the channel is free."""
        out: list[Output] = []
        while self._active is None and not self.passive:
            action = self.lifecycle.next_action(now)
            if isinstance(action, SendNmt):
                out.append(Send(0x000, bytes([action.command, self.node_id])))
                out += self._lifecycle_changes(self.lifecycle.on_nmt_sent(now), now)
                continue
            if isinstance(action, WriteStep):
                step = action.step
                out += self._start(_SdoJob(action.token, step.object, step.data, "boot", action), now)
                break
            if isinstance(action, Wait):
                self._wait_until = now + action.seconds
            break
        if self._active is None and self._jobs:
            out += self._start(self._jobs.popleft(), now)
        return out

    # ================================================================== internals: SDO
    def _start(self, job: _SdoJob, now: float) -> list[Output]:
        tr = SdoTransfer(job.obj.index, job.obj.sub, job.data, timeout_s=self.s.sdo_timeout_s, retries=self.s.sdo_retries)
        self._active = (job, tr)
        return self._sdo_frames(tr.start(now))

    def _sdo_frames(self, frames: list[bytes]) -> list[Output]:
        return [Send(0x600 + self.node_id, f) for f in frames]

    def _cancel_active(self, now: float, why: str) -> list[Output]:
        if self._active is None:
            return []
        job, tr = self._active
        tr.cancel(send_abort=False)
        self._active = None
        if job.purpose == "user":
            return [SdoDone(job.token, None, None, timed_out=True)]
        return []

    def _probe_in_flight(self) -> _SdoJob | None:
        if self._active is not None and self._active[0].purpose == "probe":
            return self._active[0]
        return next((j for j in self._jobs if j.purpose == "probe"), None)

    def _sdo_finished(self, now: float) -> list[Output]:
        assert self._active is not None
        job, tr = self._active
        self._active = None
        out: list[Output] = []
        if tr.abort_code is not None and tr.aborted_by_server:
            self.health.last_sdo_abort = tr.abort_code
        out += self._SDO_DONE[job.purpose](self, job, tr, now)
        out += self._drive(now)
        return out

    def _boot_done(self, job: _SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        ok = tr.result is not None
        code = tr.abort_code if tr.aborted_by_server else None
        return self._lifecycle_changes(self.lifecycle.on_step_result(now, ok, code, token=job.arg.token), now)

    def _probe_done(self, job: _SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        self._last_probe_end_s = now
        if tr.result is None or self.lifecycle.state is not LifecycleState.WAITING:
            return []
        device_type = int.from_bytes(tr.result[:4].ljust(4, b"\0"), "little")
        out: list[Output] = [Note(logging.INFO, f"node {self.name} (id {self.node_id}) found running")]
        out += self._lifecycle_changes(self.lifecycle.on_found(now, device_type), now)
        if self.lifecycle.state is LifecycleState.BOOTING:  # not a wrong device type
            if self.hb is not None and not self.hb.alive:
                self.hb.on_bootup(now)  # monitoring restarts as after a boot-up
            if self.guard is None or not self.guard.lost:
                out += self._set_alive(True, now)
        return out

    def _refresh_done(self, job: _SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        if tr.result is None or self.health.fresh_since is None:
            return []
        name, _obj, type_ = job.arg
        try:
            value = decode_value(tr.result, type_)
        except Exception:  # noqa: BLE001 - a short answer: the value stays stale
            return []
        return [ValuesRead((name,), (value,))]

    def _reference_done(self, job: _SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        ref = self.referencing
        assert ref is not None
        if tr.result is None:
            return [Note(logging.WARNING, f"node {self.name}: referencing state unreadable (SDO abort 0x{tr.abort_code or 0:08X})"), *self._set_referenced(False)]
        value = int.from_bytes(tr.result[:1], "little")
        return self._set_referenced(value == int(ref.get("referenced_value", 1)))

    def _user_done(self, job: _SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        out: list[Output] = [SdoDone(job.token, tr.result, tr.abort_code, tr.timed_out, tr.aborted_by_server)]
        if self.referencing is not None and job.data is not None and job.obj == ObjRef.parse(self.referencing["command"]):
            out += self._check_reference(now)
        return out

    _SDO_DONE: dict[str, Callable[[Node, _SdoJob, SdoTransfer, float], list[Output]]] = {
        "boot": _boot_done,
        "probe": _probe_done,
        "refresh": _refresh_done,
        "reference": _reference_done,
        "user": _user_done,
    }

    def _probe(self, now: float) -> list[Output]:
        """Find a node that is already running (no boot-up will come) by reading 1000h."""
        self.next_probe_s = now + self.s.probe_period_s
        if self._probe_in_flight() is not None:
            return []
        self._tokens += 1
        self._jobs.append(_SdoJob(self._tokens, OBJ_DEVICE_TYPE, None, "probe"))
        return []

    def _refresh(self, now: float) -> list[Output]:
        """Read change-only TPDOs right after NMT start (module docstring)."""
        out: list[Output] = []
        for r in self.refresh_plan:
            if r.how == "rtr":
                out.append(Send(r.codec.cob_id, b"", rtr=True, dlc=r.codec.length))
            else:
                for name, obj, type_ in r.objects:
                    self._tokens += 1
                    self._jobs.append(_SdoJob(self._tokens, obj, None, "refresh", (name, obj, type_)))
        return out

    # ================================================================== internals: features
    def _check_reference(self, now: float) -> list[Output]:
        """Feature ``referencing`` (MSK5000 5115h): read whether the position is referenced."""
        assert self.referencing is not None
        self._tokens += 1
        self._jobs.append(_SdoJob(self._tokens, ObjRef.parse(self.referencing["status"]), None, "reference"))
        return []

    def _set_referenced(self, ok: bool) -> list[Output]:
        if self.referencing is None or self.reference_signal is None:
            return []
        h = self.health
        invalid = self.reference_signal in h.invalid_signals
        if invalid == (not ok):
            return []
        h.invalid_signals = (h.invalid_signals - {self.reference_signal}) if ok else (h.invalid_signals | {self.reference_signal})
        text = f"node {self.name}: referenced; {self.reference_signal} valid" if ok else f"node {self.name}: not referenced; {self.reference_signal} is not valid"
        return [Note(logging.INFO if ok else logging.WARNING, text), HealthChanged("state")]

    def _set_nmt(self, state: NmtState) -> list[Output]:
        if self.health.nmt_state == state:
            return []
        self.health.nmt_state = state
        return [Note(logging.INFO, f"node {self.name} NMT state {state.name}"), HealthChanged("state")]

    # -- guarding bit and keep-alive
    def _link(self, changes: list[LinkOk | LinkFault]) -> list[Output]:
        out: list[Output] = []
        for ch in changes:
            out += self._set_link(LinkState.OK if isinstance(ch, LinkOk) else LinkState.FAULT)
        return out

    def _set_link(self, state: LinkState) -> list[Output]:
        h = self.health
        if h.link == state:
            return []
        out: list[Output] = []
        if state == LinkState.FAULT:
            h.link_fault_count += 1
            out.append(Note(logging.WARNING, f"node {self.name}: guarding-bit link FAULT (process data not echoed)"))
        elif h.link == LinkState.FAULT:
            out.append(Note(logging.INFO, f"node {self.name}: guarding-bit link restored"))
        h.link = state
        out.append(HealthChanged("state"))
        return out

    def _send_rpdo(self, number: int, now: float) -> list[Output]:
        codec = next(c for c in self.rpdos if c.number == number)
        values = self.outputs[number]
        if self.gbit is not None and self.control_signal is not None and self.s.guarding_bit is not None:
            i = codec.index_of(self.control_signal)
            if i is not None:
                bit = self.s.guarding_bit.control_bit
                values[i] = (int(values[i]) & ~(1 << bit)) | (self.gbit.next_bit(now) << bit)
        data = codec.encode(values)
        self.last_rpdo_s[number] = now
        self.health.rpdo_sent += 1
        return [Send(codec.cob_id, data, rpdo=True)]

    def _keepalive_due(self) -> float | None:
        if not self.keepalive_s or not self.rpdos or not self.health.alive or self.health.nmt_state != NmtState.OPERATIONAL:
            return None
        last = max(self.last_rpdo_s.values(), default=None)
        return (last + self.keepalive_s) if last is not None else (self.health.fresh_since or 0.0)

    def _keepalive(self, now: float) -> list[Output]:
        """Re-send the last RPDO when none went out for keepalive_s: feeds the AP05 external
        heartbeat (source RPDO, manual 5.5.4) and exercises the guarding bit (manual 5.5.5)
        when the PLC writes nothing. Only in OPERATIONAL (RPDOs are not processed otherwise)."""
        number = max(self.last_rpdo_s, key=self.last_rpdo_s.__getitem__, default=self.rpdos[-1].number)
        return self._send_rpdo(number, now)

    def _rtr_poll(self, now: float) -> list[Output]:
        assert self.s.rtr_poll_ms
        self._rtr_due_s = now + self.s.rtr_poll_ms / 1000.0
        if self.health.nmt_state != NmtState.OPERATIONAL:
            return []
        return [Send(c.cob_id, b"", rtr=True, dlc=c.length) for c in self.tpdos]
