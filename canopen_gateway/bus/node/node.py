"""One CANopen device as the master sees it: the single owner of the node's state.

Rule 1: everything the gateway decides about one node lives here, in ``Node``: its lifecycle,
its supervision (heartbeat consumer or node guarding, the guarding-bit check, the RPDO
keep-alive), its SDO channel (one transfer at a time: boot steps, probes, refreshes, commands),
its output image (the last values sent in each RPDO) and its health in the process image
(``NodeHealth``: only this class writes it). It writes the image's output section
(``NodeImage.outputs``) too, in one assignment after each write or keep-alive: the one copy of
the outputs that Modbus, Zenoh and the web console read.
The device features (refresh on start, referencing, verify mapping, RTR poll, waiting for
SYNC-driven TPDOs without a SYNC producer; built by ``bus.node.parts``) are hooks it calls
(``bus/node/features/``), not branches of its own; each sees the node as a ``NodeContext``.
What its lifecycle reports (``lifecycle_report``) and what a finished transfer of its own
purposes means (``sdo_done``) come back as values the node applies; neither writes the node.
Rule 2: no I/O and no clock. The driver (``bus.master``) feeds events with the time ``now``
(the bus clock: the time of the frames processed, seconds) — ``on_nmt_ec``, ``on_emcy``,
``on_echo``, ``on_sdo_response``, ``on_bus_down``, ``tick``, ``request_sdo``, ``write_outputs``,
``on_nmt_command`` — and executes what they return: ``Send`` frames, ``SdoDone`` results,
``ValuesRead``, ``HealthChanged`` and ``Note`` (log lines). ``next_deadline()`` says when
``tick`` is next due; the driver sleeps until the earliest deadline of all nodes.
Rule 3: queued work never waits for an unrelated timer. A handler that queues SDO work starts it
when the channel is free (``_drive``); while work is queued and no transfer runs, the channel's
deadline is when it was queued (``SdoChannel.next_deadline``): the node is ticked at once.
The decisions are tables: ``GUARD_EXPECTS`` (lifecycle_actions), ``NMT_EXPECTS`` (node_supervision),
``SDO_DONE``; a node another master manages (a pair's standby) is in lifecycle LISTENING:
``bus.node.listening``.

Truthfulness (docs/architecture.md, "Two flows"): a boot-up and a loss invalidate every value of
the node (``fresh_since = None``; a loss says why in ``last_error`` at once); values are good
again only when received after the gateway's NMT start; change-only TPDOs are read right after.

Imports: bus.node.* (lifecycle, lifecycle_report, listening, outputs, probes, features, sdo_done), bus.events,
device.* (boot_steps, settings), bus.sdo.*, bus.error_control.*, bus.emcy (the history), pdo.codec,
pdo.verify, canopen.* (cia301, emcy, states, objref), errors, image, logging (log levels). Never python-can, asyncio or a northbound module.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from canopen_gateway.bus.emcy import EmcyHistory
from canopen_gateway.bus.error_control.guarding_bit import GuardingBitCheck
from canopen_gateway.bus.error_control.node_supervision import NodeSupervision
from canopen_gateway.bus.events import HealthChanged, Note, Output, Refresh, SdoDone, Send
from canopen_gateway.bus.node import listening
from canopen_gateway.bus.node.features import NodeFeature
from canopen_gateway.bus.node.features.guarding_bit import GuardingBitLink
from canopen_gateway.bus.node.features.refresh import RefreshOnStart
from canopen_gateway.bus.node.features.verify_mapping import VerifyMapping
from canopen_gateway.bus.node.lifecycle import (
    Change,
    LifecycleState,
    NodeLifecycle,
    ReadIdentity,
    SendNmt,
    Wait,
    WriteStep,
)
from canopen_gateway.bus.node.lifecycle_report import lifecycle_reports
from canopen_gateway.bus.node.listening import HeardLife, resume_wait_s
from canopen_gateway.bus.node.outputs import OutputImage
from canopen_gateway.bus.node.probes import Probes
from canopen_gateway.bus.node.sdo_done import SDO_DONE, SdoOutcome
from canopen_gateway.bus.sdo.channel import SdoChannel, SdoJob
from canopen_gateway.bus.sdo.client import SdoTransfer
from canopen_gateway.canopen.cia301 import COB_NMT, COB_NMT_EC
from canopen_gateway.canopen.emcy import decode_emcy
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.device.boot_steps import ConfigStep
from canopen_gateway.device.settings import NodeSettings
from canopen_gateway.errors import NodeNotOperational
from canopen_gateway.image import NodeHealth, NodeImage
from canopen_gateway.pdo.codec import RpdoCodec, TpdoCodec
from canopen_gateway.pdo.verify import MappingMismatch

OBJ_DEVICE_TYPE = ObjRef(0x1000, 0x00)


class Node:
    """The state of one node (see the module docstring)."""

    def __init__(
        self, name: str, node_id: int, settings: NodeSettings, health: NodeHealth, *,
        boot_steps: Sequence[ConfigStep] = (),
        configure: bool = True,
        tpdos: Sequence[TpdoCodec] = (),
        rpdos: Sequence[RpdoCodec] = (),
        features: Sequence[NodeFeature] = (),
        expected_device_type: int | None = None,
        expected_identity: Sequence[tuple[ObjRef, int]] = (),
        emcy_texts: dict[int, str] | None = None,
        guard_names: tuple[str | None, str | None] = (None, None),
        listening: bool = False,
        image: NodeImage | None = None,
    ):
        """``features``: in the order they act (``bus.node.parts``). ``listening``: another
        master manages the node (lifecycle LISTENING, ``bus.node.listening``)."""
        self.name = name
        self.node_id = node_id
        self.s = settings
        self.health = health
        self.tpdos = list(tpdos)
        self.rpdos = list(rpdos)
        self.emcy_texts = emcy_texts or {}
        self.boot_steps = tuple(boot_steps)
        self.lifecycle = NodeLifecycle(
            self.boot_steps if configure else [],
            boot_timeout_s=settings.boot_timeout_s,
            expected_device_type=expected_device_type,
            expected_identity=expected_identity, resume_wait_s=resume_wait_s(settings),
        )
        self.supervision = NodeSupervision(settings, configure)
        self.heard, self.resumes = HeardLife(), listening  # a pair's: what it heard; resumes
        if listening:  # no RTR, no life time of ours (``NodeSupervision.on_lifecycle``)
            self.lifecycle.on_listen(0.0)
            self.supervision.on_lifecycle(LifecycleState.LISTENING.guard_expects, listening=True)
        self.hb, self.guard = self.supervision.hb, self.supervision.guard  # read-only views
        self.features = list(features)  # bus/node/features/
        self._link = next((f for f in self.features if isinstance(f, GuardingBitLink)), None)
        self.gbit: GuardingBitCheck | None = self._link.check if self._link else None
        self.control_signal, self.status_signal = guard_names
        health.supervision = settings.supervision
        health.link = LinkState.UNKNOWN if self.gbit is not None else LinkState.NOT_USED
        self.emcy = EmcyHistory()
        gb = settings.guarding_bit
        control = (self.control_signal, gb.control_bit) if gb and self.control_signal else None
        self.outputs = OutputImage(  # a pair's member (listening at first): ``pair``
            name, self.rpdos, settings.keepalive_ms / 1e3, self.gbit, control, pair=listening
        )
        self.image = image  # its ``outputs`` section is written here only
        self._publish_outputs()
        self.sdo = SdoChannel(node_id, settings.sdo_timeout_s, settings.sdo_retries)
        self.probes = Probes(settings.probe_period_s)  # when a node waited for is probed
        self._wait_until: float | None = None
        self._by_purpose = {p: f for f in self.features for p in f.purposes}

    # ================================================================== queries
    @property
    def alive(self) -> bool:
        return self.health.alive

    @property
    def listening(self) -> bool:
        """Another master manages the node: it is only heard (lifecycle LISTENING)."""
        return self.lifecycle.state is LifecycleState.LISTENING

    @property
    def steady(self) -> bool:
        """A repeated heartbeat changes nothing before its consumer deadline (no wake-up)."""
        steady = (LifecycleState.OPERATIONAL, LifecycleState.LISTENING)
        return self.s.supervision == "heartbeat" and self.alive and self.lifecycle.state in steady

    @property
    def refresh_plan(self) -> list[Refresh]:
        return next((f.plan for f in self.features if isinstance(f, RefreshOnStart)), [])

    @property
    def mapping_mismatches(self) -> list[MappingMismatch]:
        return next((f.mismatches for f in self.features if isinstance(f, VerifyMapping)), [])

    def next_deadline(self) -> float | None:
        times = [
            self.lifecycle.next_deadline(),
            self.supervision.next_deadline(),
            self.sdo.next_deadline(),
            self._probe_due_s(),
            self._keepalive_due(),
            self._wait_until,
            *(f.next_deadline() for f in self.features),
        ]
        return min((t for t in times if t is not None), default=None)

    def output(self, name: str, pdo: int | None = None) -> Any:
        """The last value sent for signal ``name`` (in RPDO ``pdo``, default: the last one)."""
        return self.outputs.get(name, pdo)

    def is_output(self, name: str) -> bool:
        return self.outputs.is_output(name)

    @property
    def by_signal(self) -> dict[str, list[RpdoCodec]]:
        return self.outputs.by_signal

    def sdo_busy(self) -> bool:  # a transfer is running or waiting
        return self.sdo.busy

    # ================================================================== events
    def start(self, now: float, probe: bool = True) -> list[Output]:
        if self.listening:
            return listening.report_heard(self)  # listening only: no boot timeout of ours to report
        self.health.lifecycle = str(self.lifecycle.state)
        self.lifecycle.start(now)
        self.probes.at(now if probe else now + self.s.probe_period_s)
        return self.tick(now)

    def tick(self, now: float) -> list[Output]:
        """Time has passed: timeouts, retries, scheduled frames."""
        frames, finished = self.sdo.poll(now)
        out: list[Output] = [*frames]
        if finished is not None:
            out += self._sdo_finished(finished, now)
        rtr, lost = self.supervision.poll(now)
        if rtr:
            out.append(Send(COB_NMT_EC + self.node_id, b"", rtr=True, dlc=1))
        if lost is not None:
            out += self._set_alive(False, now, lost)
        out += self._lifecycle_changes(self.lifecycle.poll(now), now)
        for f in self.features:
            out += f.tick(self, now)
        if self._wait_until is not None and now >= self._wait_until:
            self._wait_until = None
        if (due := self._keepalive_due()) is not None and now >= due:
            self.health.rpdo_sent += 1
            out.append(self.outputs.keepalive(now))
            self._publish_outputs()  # the guarding bit of the control word as sent
        due = self._probe_due_s()
        if due is not None and now >= due:
            out += self._probe(now)
        out += self._drive(now)
        return out

    def on_nmt_ec(self, byte: int, now: float) -> list[Output]:
        """A frame on 700h + node id: boot-up (00h), heartbeat, or node-guarding answer."""
        if byte == NmtState.BOOTUP:
            return self._bootup(now)
        state, problems = self.supervision.answer(byte, now)
        out: list[Output] = [
            Note(logging.WARNING, f"node {self.name}: {p}", ("guard", self.name, p.split(":")[0]))
            for p in problems
        ]
        if state is None:  # not valid (a toggle or state error): the state it reports still tells
            return out + listening.heard_invalid(self, byte, now)
        out += self._set_nmt(state)
        if self.supervision.alive:
            out += self._set_alive(True, now)
        if self.listening:
            return out + listening.on_state(self, state, now)
        out += listening.watch_fall(self, state, now)  # adopted at a take-over: fallen?
        if self.lifecycle.state is LifecycleState.WAITING:
            out += self._found_alive(state, now)
        return out

    def _found_alive(self, state: NmtState, now: float) -> list[Output]:
        """Alive, no boot-up seen (gateway restarted, node replugged): probe soon (not a refused
        device before its recheck); a pair's node lost running and heard so again resumes."""
        if self.resumes and listening.resumes_in(self, state):
            self.health.fresh_since = now  # a split healed: no NMT, no SDO; fresh from now on
            self.outputs.hold(now + self.lifecycle.resume_wait_s)  # another master met meanwhile?
            return self._lifecycle_changes(self.lifecycle.on_resumed(now), now) + listening.adopted(self, state, now)
        if self.lifecycle.may_probe(now) and self.sdo.find("probe") is None and self.probes.rested(now):
            return self._probe(now) + self._drive(now)
        return []

    def on_emcy(self, data: bytes, wall_ts: float, now: float) -> list[Output]:
        h = self.health
        if len(data) < 3:
            h.emcy_errors += 1
            text = f"node {self.name}: EMCY with {len(data)} bytes ignored"
            return [Note(logging.WARNING, text, ("emcy_short", self.name))]
        rec = decode_emcy(bytes(data), self.emcy_texts, wall_ts)
        self.emcy.add(rec)
        h.last_emcy = rec  # type: ignore[assignment]
        h.emcy_count += 1
        h.emcy_history = tuple(self.emcy.history)
        h.current_errors = sorted(self.emcy.current)
        text = f"node {self.name} EMCY 0x{rec.code:04X} ({rec.text}) register 0x{rec.register:02X}"
        out: list[Output] = [Note(logging.WARNING, text), HealthChanged("emcy")]
        if not self.listening and any([f.on_emcy(self, now) for f in self.features]):
            out += self._drive(now)  # start what a feature queued now if the channel is free
        return out

    def on_echo(self, bit: int, now: float) -> list[Output]:
        """The guarding bit of a status word just received in a TPDO (AP05 manual 5.5.5)."""
        return self._link.on_echo(self, bit, now) if self._link is not None else []

    def on_sdo_response(self, data: bytes, now: float) -> list[Output]:
        frames, finished = self.sdo.on_response(data, now)
        out: list[Output] = [*frames]
        if finished is not None:
            out += self._sdo_finished(finished, now)
        self.supervision.on_sign_of_life(now, self.lifecycle.state.answers_configuration)
        return out

    def on_bus_down(self, now: float) -> list[Output]:
        """The bus is down: the node's state is not known any more."""
        return self._set_nmt(NmtState.UNKNOWN)

    def request_sdo(
        self, obj: ObjRef, data: bytes | None, now: float, purpose: str = "user", arg: Any = None
    ) -> tuple[int, list[Output]]:
        """Queue an SDO upload (``data`` None) or download; ``SdoDone(token)`` reports it."""
        token = self.sdo.queue(obj, data, purpose, now, arg)
        return token, self._drive(now)

    def on_nmt_command(self, command: str) -> None:
        """An NMT command to this node (a client's, or heard while listening)."""
        self.supervision.on_nmt_command(command)
        listening.commanded(self, command)

    def on_guard_rtr(self, now: float) -> list[Output]:
        """Another master's guarding RTR heard while listening (``on_rtr_heard``: lost?)."""
        lost = self.supervision.on_rtr_heard()
        return self._set_alive(False, now, lost) if lost is not None else []

    # ================================================================== a pair's roles
    def on_rpdo_heard(self, cob_id: int, data: bytes, wall: float, now: float) -> list[Output]:
        """An RPDO another master sent: its values become the output image (a write heard
        counts as one: the output watchdog of a take-over counts from it); while mastering,
        only into an RPDO not known here (``OutputImage.forget``)."""
        known = not self.listening and self.outputs.knows(cob_id)
        wrote = None if known else self.outputs.heard(cob_id, data, now)
        if wrote is not None:
            self._publish_outputs((wall, now) if wrote else None)
        return []

    def stand_by(self, now: float, fresh: bool = False) -> list[Output]:
        """A pair's standby: the node only listens, queued SDO work dropped (``fresh``: the
        member is back from its own outage, and the node listens as a fresh joiner)."""
        self.heard.stood_down(self.lifecycle.state, self.health.nmt_state, fresh)
        if fresh or self.lifecycle.state is LifecycleState.WAITING:
            self.outputs.forget()  # what another master sent it meanwhile is not known here
        out = self._end_sdo_work(now, lambda j: False)
        return out + self._lifecycle_changes(self.lifecycle.on_listen(now), now) + listening.report_heard(self)

    def take_over(self, now: float, master_heard: bool = True) -> list[Output]:
        """The pair's take-over: a node heard started is adopted as it runs (``listening``)."""
        if not self.listening:
            return self.tick(now)  # ours already: nothing to take over
        adopt, sent, resumes = listening.take_over(self, now, master_heard)
        out = self._lifecycle_changes(self.lifecycle.on_take_over(now, adopt is not None, resumes), now)
        if adopt is None:
            self.probes.at(now)  # found and configured as usual
        else:
            self.outputs.resume(now)  # keep-alives go on at once
        return out + listening.adopted(self, adopt, now) + sent + self.tick(now)

    def write_outputs(
        self,
        per_pdo: dict[int | None, dict[str, Any]],
        now: float,
        send: Sequence[int] | None = None,
        *,
        wall: float = 0.0,
        safe: bool = False,
    ) -> list[Output]:
        """Set output values and send the RPDOs that carry them (one frame per RPDO).

        ``per_pdo``: as ``OutputImage.set`` (which RPDOs go out, unless ``send`` says). The
        image's output section then holds the new values (``wall``: the write's time). Raises
        NodeNotOperational (nothing changed) when the node is not operational. ``safe``: these
        are the safe values of the output watchdog (the node's ``outputs`` health says ``safe``
        until the next write)."""
        self.require_operational()
        numbers = list(send) if send else self.outputs.set(per_pdo)
        if send:
            self.outputs.set(per_pdo)
        self.health.rpdo_sent += len(numbers)
        out: list[Output] = [self.outputs.frame(n, now) for n in numbers]
        mode = "safe" if safe else "normal"
        if self.health.outputs != mode:
            self.health.outputs = mode
            out.append(HealthChanged("state"))
        self._publish_outputs((wall, now))
        return out

    def _publish_outputs(self, written: tuple[float, float] | None = None) -> None:
        """The output image as set now into the process image, in one assignment (``written``:
        the wall-clock and bus-clock times of a write)."""
        sent = self.outputs.published(written)
        if self.image is not None:
            self.image.outputs = sent

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
        self.supervision.on_bootup(now)
        self.emcy.clear()
        h.current_errors = []
        for f in self.features:
            out += f.on_bootup(self, now)
        out += self._set_nmt(NmtState.PRE_OPERATIONAL)
        out += self._set_alive(True, now)
        # a boot-up ends whatever transfer was running: the device forgot it
        out += self._end_sdo_work(now, lambda j: j.purpose == "user")
        if self.listening:
            return out + listening.on_restart(self)
        out += self._lifecycle_changes(self.lifecycle.on_bootup(now), now)
        out += self._drive(now)
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
            for f in self.features:
                out += f.on_lost(self)
            h.last_error = f"lost ({reason or self.s.supervision})"
            out.append(Note(logging.WARNING, f"node {self.name} (id {self.node_id}) {h.last_error}"))
            if self.listening:
                out += listening.on_lost(self)  # gone, or this gateway deaf: not a restart
            else:
                out += self._lifecycle_changes(self.lifecycle.on_lost(now), now)
                self.probes.later(now)  # cadence counted from the loss
        else:
            h.last_error = "" if h.last_error.startswith("lost (") else h.last_error  # loss over
            out.append(Note(logging.INFO, f"node {self.name} (id {self.node_id}) alive"))
        out.append(HealthChanged("state"))
        return out

    def _invalidate(self) -> None:
        self.health.fresh_since = None
        for f in self.features:
            f.on_invalidate(self)

    def _lifecycle_changes(self, changes: Sequence[Change], now: float) -> list[Output]:
        """What the lifecycle reported (``lifecycle_report``): health fields, log lines, what
        guarding expects, and once configured fresh values and the features' ``on_configured``."""
        h = self.health
        out: list[Output] = []
        for r in lifecycle_reports(changes, self.name, self.node_id, self.lifecycle.last_error, now):
            out.append(r.note)
            if r.state is not None:
                h.lifecycle = str(r.state)
                self.supervision.on_lifecycle(r.state.guard_expects, r.state is LifecycleState.LISTENING)
                if r.state is LifecycleState.LISTENING:
                    listening.report_heard(self)
            if r.last_error is not None:
                h.last_error = r.last_error
            if r.last_sdo_abort is not None:
                h.last_sdo_abort = r.last_sdo_abort
            if r.wait_until_s is not None:
                self._wait_until = r.wait_until_s
            if r.configured:
                h.fresh_since = now  # values are good again when received from now on
                self.outputs.own()  # configured here: every RPDO's content is ours
                if self.supervision.hb is None and self.supervision.guard is None:
                    out += self._set_nmt(NmtState.OPERATIONAL)  # no heartbeat will confirm it
                for f in self.features:
                    out += f.on_configured(self, now)
        if changes:
            out.append(HealthChanged("state"))
        return out

    def _drive(self, now: float) -> list[Output]:
        """Start the next SDO transfer / NMT command when the channel is free."""
        out: list[Output] = []
        while self.sdo.idle and not self.listening:
            action = self.lifecycle.next_action(now)
            if isinstance(action, SendNmt):
                out.append(Send(COB_NMT, bytes([action.command, self.node_id])))
                out += self._lifecycle_changes(self.lifecycle.on_nmt_sent(now), now)
                continue
            if isinstance(action, WriteStep):
                step = action.step
                out += self.sdo.start(
                    SdoJob(action.token, step.object, step.data, "boot", action), now
                )
                break
            if isinstance(action, ReadIdentity):
                out += self.sdo.start(SdoJob(action.token, action.object, None, "identity", action), now)
                break
            if isinstance(action, Wait):
                self._wait_until = now + action.seconds
            break
        if self.sdo.idle:
            out += self.sdo.start_next(now)
        return out

    # ================================================================== internals: SDO
    def _end_sdo_work(self, now: float, keep: Callable[[SdoJob], bool]) -> list[Output]:
        """Cancel the running transfer (a client's is answered: timed out); of the queued work,
        only what ``keep`` selects stays (``SdoChannel.drop``)."""
        cancelled = self.sdo.cancel_active(now)
        self.sdo.drop(keep)
        if cancelled is not None and cancelled.purpose == "user":
            return [SdoDone(cancelled.token, None, None, timed_out=True)]
        return []

    def _probe_due_s(self) -> float | None:
        """When the next probe is due (``Probes``); a pair's node lost running says itself
        when it is back (no probe to reconfigure it)."""
        heard_back = self.resumes and self.lifecycle.resumable and self.s.supervision != "none"
        return self.probes.due_s(self.lifecycle, heard_back)

    def _sdo_finished(self, finished: tuple[SdoJob, SdoTransfer], now: float) -> list[Output]:
        job, tr = finished
        if tr.abort_code is not None and tr.aborted_by_server:
            self.health.last_sdo_abort = tr.abort_code
        done = SDO_DONE.get(job.purpose)
        if done is not None:
            out = self._take_sdo_outcome(done(self, job, tr, now), job, now)
        else:  # a feature's own transfer
            out = self._by_purpose[job.purpose].sdo_done(self, job, tr, now)
        return out + self._drive(now)

    def _take_sdo_outcome(self, r: SdoOutcome, job: SdoJob, now: float) -> list[Output]:
        """What a transfer of the node's own purposes meant (``sdo_done``), applied."""
        if r.probe_ended:
            self.probes.ended(now, r.probe_again_s)
        out = [*r.outputs, *self._lifecycle_changes(r.changes, now)]
        if r.found:
            self.supervision.on_found(now)
            if not self.supervision.guard_lost:
                out += self._set_alive(True, now)
        if r.user:
            for f in self.features:
                out += f.on_user_sdo(self, job, now)
        return out

    def _probe(self, now: float) -> list[Output]:
        """Find a node that is already running (no boot-up will come) by reading 1000h."""
        self.probes.later(now)
        if self.sdo.find("probe") is None:
            self.sdo.queue(OBJ_DEVICE_TYPE, None, "probe", now)
        return []

    def _set_nmt(self, state: NmtState) -> list[Output]:
        if self.health.nmt_state == state:
            return []
        self.health.nmt_state = state
        return [Note(logging.INFO, f"node {self.name} NMT state {state.name}"), HealthChanged("state")]

    # -- guarding bit and keep-alive
    def _keepalive_due(self) -> float | None:
        """Keep-alive RPDOs only in OPERATIONAL (RPDOs are not processed otherwise)."""
        h = self.health
        if self.listening or not h.alive or h.nmt_state != NmtState.OPERATIONAL:
            return None
        return self.outputs.keepalive_due(h.fresh_since)
