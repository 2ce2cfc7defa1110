"""The CANopen NMT master: node runtimes, boot-up configuration, supervision, SDO, NMT, SYNC.

Runs on the asyncio event loop. The reader thread of ``BusDriver`` decodes process data itself
and forwards control traffic (heartbeat / guarding answers, EMCY, boot-up) here with
``loop.call_soon_threadsafe``. The protocol decisions are taken by the plain state machines of
``lifecycle``, ``supervision`` and ``emcy``; this module only wires them to time and I/O.

SDO transfers use canopen's SDO client (expedited and segmented) on a ``canopen.Network`` whose
sending goes through our driver; one transfer per node at a time (an asyncio lock per node),
several nodes in parallel (each in a worker thread).

Imports: bus.*, image, profiles, errors, config. Nothing northbound.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

import can
import canopen
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from gateway.bus.codec import RpdoCodec, TpdoCodec, compile_node
from gateway.bus.driver import BusDriver, RateLimitedLog
from gateway.bus.emcy import EmcyHistory, decode_emcy
from gateway.bus.lifecycle import (
    OD_TYPE_NAMES,
    BootTimeout,
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
    build_boot_steps,
    decode_value,
    encode_value,
)
from gateway.bus.supervision import (
    GuardingBitCheck,
    HeartbeatConsumer,
    InvalidStateByte,
    NodeGuardingMaster,
    SendGuardRtr,
    ToggleError,
    WrongState,
)
from gateway.bus.supervision import (
    NmtState as SupNmt,
)
from gateway.bus.verify import MappingMismatch, compare_mapping, mapping_reads
from gateway.config import Config, NodeConfig
from gateway.errors import BusDown, NodeNotOperational, SdoAbort, SdoTimeout
from gateway.image import LinkState, NmtState, NodeImage, ProcessImage
from gateway.objref import ObjRef
from gateway.profiles import LoadedProfile, load_node_profile, node_verifies_mapping

log = logging.getLogger("gateway.master")

NMT_COMMANDS = {"start": 0x01, "stop": 0x02, "preop": 0x80, "reset": 0x81, "reset-comm": 0x82}

class _Network(canopen.Network):
    """A canopen Network that sends through our driver and is fed by our reader thread."""

    def __init__(self, driver: BusDriver):
        super().__init__()
        self._driver = driver
        self.bus = True  # canopen only checks truthiness

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self._driver.send(can_id, bytes(data), rtr=remote)

    def check(self) -> None:
        return None


class NodeRuntime:
    """Everything the master knows about one configured node."""

    def __init__(self, cfg: NodeConfig, lp: LoadedProfile, image: NodeImage, master: Master):
        self.cfg = cfg
        self.lp = lp
        self.image = image
        self.node_id = cfg.node_id
        self.name = cfg.name
        self.sdo_lock = asyncio.Lock()
        self.remote = canopen.RemoteNode(cfg.node_id, lp.od)
        self.remote.sdo.RESPONSE_TIMEOUT = master.cfg.master.sdo_timeout_s
        # canopen counts attempts (1 = no retry); the config counts retries after the first
        self.remote.sdo.MAX_RETRIES = master.cfg.master.sdo_retries + 1
        supervision = cfg.supervision or lp.profile.boot.supervision
        self.supervision = supervision
        image.health.supervision = supervision
        hb_ms = cfg.heartbeat_ms if cfg.heartbeat_ms is not None else lp.profile.boot.heartbeat_ms
        gt_ms = cfg.guard_time_ms if cfg.guard_time_ms is not None else lp.profile.boot.guard_time_ms
        ltf = (
            cfg.life_time_factor
            if cfg.life_time_factor is not None
            else lp.profile.boot.life_time_factor
        )
        self.heartbeat_ms, self.guard_time_ms, self.life_time_factor = hb_ms, gt_ms, ltf
        # With configuration, the boot-up counts as a sign of life and the first heartbeat
        # must follow within the boot timeout (1017h is written first): a node dying during
        # its configuration is reported lost instead of staying "alive" forever.
        grace_s = master.cfg.master.boot_timeout_s if cfg.configure else None
        self.hb: HeartbeatConsumer | None = (
            HeartbeatConsumer(hb_ms, master.cfg.master.heartbeat_timeout_multiple, grace_s)
            if hb_ms > 0
            else None
        )
        self.guard = NodeGuardingMaster(gt_ms, ltf) if supervision == "guarding" else None
        steps = build_boot_steps(lp, cfg, supervision, hb_ms, gt_ms, ltf)
        self.boot_steps = steps
        # The decoder follows the mapping the boot configuration leaves in the device (profile
        # layout or variant, then the PDO writes of the steps in order; see codec module).
        writes = [(st.object, st.value) for st in steps] if cfg.configure else []
        self.tpdos, self.rpdos = compile_node(lp, cfg.node_id, cfg.pdo_variant, writes)
        # verify_mapping (gateway.bus.verify): read the PDO objects back after configuring
        self.verify_mapping = cfg.configure and node_verifies_mapping(lp, cfg, cfg.eds_only)
        self.mapping_mismatches: list[MappingMismatch] = []
        # a signal may be mapped in several RPDOs (AP05 control word 5F0Ch is in RPDO1 and 2)
        self.rpdo_by_signal: dict[str, list[RpdoCodec]] = {}
        for r in self.rpdos:
            for n in r.names:
                self.rpdo_by_signal.setdefault(n, []).append(r)
        self.next_probe_s: float | None = None
        self.pdo_too_long = 0
        # configure: false -> no SDO steps; the lifecycle only sends NMT pre-operational (when
        # found running) and NMT start
        self.lifecycle = NodeLifecycle(
            steps if cfg.configure else [],
            boot_timeout_s=master.cfg.master.boot_timeout_s,
            expected_device_type=lp.profile.device_type,
        )
        self.emcy = EmcyHistory()
        gb = lp.profile.features.get("guarding_bit")
        self.guarding_bit: dict[str, Any] | None = (
            gb if gb is not None and cfg.guarding_bit.enabled else None
        )
        self.gbit = (
            GuardingBitCheck(
                tolerance_missed=cfg.guarding_bit.tolerance_missed,
                tolerance_s=cfg.guarding_bit.tolerance_ms / 1000.0,
            )
            if self.guarding_bit
            else None
        )
        if self.gbit is not None:
            image.health.link = LinkState.UNKNOWN
        self.last_rpdo_sent: dict[int, float] = {}
        self.referencing: dict[str, Any] | None = lp.profile.features.get("referencing")
        self.reference_signal: str | None = None
        if self.referencing is not None:
            pos = lp.profile.signal_for(ObjRef.parse(self.referencing.get("position", "0x6004:00")))
            self.reference_signal = pos.name if pos is not None else None
        periods = []
        if self.gbit is not None:
            periods.append(cfg.guarding_bit.period_ms / 1000.0)
        eh = cfg.external_heartbeat
        if eh is not None and eh.source == "rpdo":
            periods.append((eh.keepalive_ms or max(1, eh.interval_ms // 2)) / 1000.0)
        self.keepalive_s = min(periods) if periods else 0.0


class Master:
    """The NMT master of the configured nodes (see the module docstring).

    ``passive = True`` (commissioning tools: ``canopen-gateway sdo|nmt``) keeps supervision
    and the services but takes no lifecycle action on its own: no probe, no configuration, no
    NMT start after a boot-up.
    """

    def __init__(self, cfg: Config, image: ProcessImage, driver: BusDriver):
        self.cfg = cfg
        self.image = image
        self.driver = driver
        self.passive = False
        self.loop: asyncio.AbstractEventLoop | None = None
        self.network = _Network(driver)
        self.nodes: dict[str, NodeRuntime] = {}
        self.by_id: dict[int, NodeRuntime] = {}
        self._tasks: list[asyncio.Task[Any]] = []
        self._probes: dict[str, asyncio.Task[Any]] = {}
        self._config_tasks: dict[str, asyncio.Task[Any]] = {}
        self.warn = RateLimitedLog(log)
        self.rpdo_hooks: list[Callable[[NodeRuntime, RpdoCodec], None]] = []
        for ncfg in cfg.nodes:
            lp = load_node_profile(ncfg, cfg.base_dir)
            names = [s.name for s in lp.profile.signals]
            stale = ncfg.stale_after_ms / 1000.0 if ncfg.stale_after_ms else None
            ni = NodeImage(ncfg.name, ncfg.node_id, lp.family, names, stale, ncfg.modbus.serve_stale)
            image.add_node(ni)
            rt = NodeRuntime(ncfg, lp, ni, self)
            self.nodes[ncfg.name] = rt
            self.by_id[ncfg.node_id] = rt
            self.network.add_node(rt.remote)
        self._install_handlers()

    # ------------------------------------------------------------------ dispatch (reader thread)
    def _install_handlers(self) -> None:
        h = self.driver.handlers
        for rt in self.nodes.values():
            for codec in rt.tpdos:
                h[codec.cob_id] = self._tpdo_handler(rt, codec)
            h[0x700 + rt.node_id] = self._forward(self._on_nmt_ec, rt)
            h[0x080 + rt.node_id] = self._forward(self._on_emcy, rt)
            h[0x580 + rt.node_id] = self._sdo_response
        h[0x7E4] = self._sdo_response  # LSS responses go to canopen's LSS master
        self.driver.default_handler = self._unknown

    def _tpdo_handler(self, rt: NodeRuntime, codec: TpdoCodec) -> Callable[[can.Message], None]:
        image = self.image
        node = rt.image
        decode = codec.decode
        names = codec.names
        length = codec.length
        update = image.update
        gb = rt.guarding_bit
        status_name = None
        if gb is not None:
            sig = rt.lp.profile.signal_for(ObjRef.parse(gb["status"]))
            if sig is not None and sig.name in names:
                status_name = sig.name
        status_pos = names.index(status_name) if status_name else -1
        status_mask = 1 << int(gb.get("status_bit", 8)) if gb else 0

        pdo_listeners = image.pdo_listeners

        def handle(msg: can.Message) -> None:
            data = msg.data
            if msg.is_remote_frame:
                return
            if len(data) < length:
                node.health.pdo_errors += 1
                image.counters["decode_errors"] += 1
                self.warn.warning(
                    ("short", codec.cob_id),
                    "node %s: PDO 0x%03X with %d bytes, mapping needs %d; ignored",
                    node.name,
                    codec.cob_id,
                    len(data),
                    length,
                )
                return
            if len(data) > length:
                # CiA 301: a PDO longer than its mapping is processed (the mapped bytes)
                rt.pdo_too_long += 1
                self.warn.warning(
                    ("long", codec.cob_id),
                    "node %s: PDO 0x%03X with %d bytes, mapping has %d; extra bytes ignored",
                    node.name,
                    codec.cob_id,
                    len(data),
                    length,
                )
            values = decode(data)
            update(node, names, values, msg.timestamp or time.time())
            if pdo_listeners:
                raw = bytes(data)
                for listener in pdo_listeners:
                    listener(node, codec.cob_id, raw)
            if status_pos >= 0 and self.loop is not None:
                echoed = 1 if values[status_pos] & status_mask else 0
                self.loop.call_soon_threadsafe(self._on_guarding_echo, rt, echoed)

        return handle

    def _forward(
        self, fn: Callable[[NodeRuntime, can.Message], None], rt: NodeRuntime
    ) -> Callable[[can.Message], None]:
        def handle(msg: can.Message) -> None:
            if self.loop is not None:
                self.loop.call_soon_threadsafe(fn, rt, msg)

        return handle

    def _sdo_response(self, msg: can.Message) -> None:
        self.network.notify(msg.arbitration_id, msg.data, msg.timestamp)

    def _unknown(self, msg: can.Message) -> None:
        cob = msg.arbitration_id
        if cob in (0x000, 0x080) or cob == 0x700 + self.cfg.master.node_id:
            return  # NMT / SYNC from another master or our own echo
        self.image.counters["unknown_cob_id"] += 1
        self.warn.warning(("unknown", cob), "frame with unexpected COB-ID 0x%03X ignored", cob)

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._tasks.append(asyncio.create_task(self._supervise(), name="supervise"))
        if self.cfg.master.heartbeat_ms:
            self._tasks.append(asyncio.create_task(self._heartbeat_producer(), name="hb-producer"))
        if self.cfg.master.sync_period_ms:
            self._tasks.append(asyncio.create_task(self._sync_producer(), name="sync"))
        now = time.monotonic()
        for rt in self.nodes.values():
            rt.lifecycle.start(now)
            rt.image.health.lifecycle = str(rt.lifecycle.state)
            if rt.cfg.rtr_poll_ms:
                self._tasks.append(asyncio.create_task(self._rtr_poll(rt)))
        for rt in self.nodes.values():
            if self.cfg.master.probe_at_start and not self.passive:
                self._spawn_probe(rt)
            else:
                rt.next_probe_s = now + self.cfg.master.boot_timeout_s

    async def stop(self) -> None:
        tasks = list(self._tasks) + list(self._config_tasks.values()) + list(self._probes.values())
        for t in tasks:
            t.cancel()
        for t in tasks:
            try:
                await t
            except (asyncio.CancelledError, Exception):  # noqa: BLE001
                pass
        self._tasks.clear()
        self._config_tasks.clear()
        self._probes.clear()

    def _spawn_probe(self, rt: NodeRuntime) -> None:
        """Probe ``rt`` unless a probe is already running; the next periodic probe is due one
        boot timeout later."""
        rt.next_probe_s = time.monotonic() + self.cfg.master.boot_timeout_s
        if self.passive or rt.name in self._probes:
            return
        task = asyncio.create_task(self._probe(rt), name=f"probe-{rt.name}")
        self._probes[rt.name] = task
        task.add_done_callback(lambda _t, name=rt.name: self._probes.pop(name, None))

    async def _probe(self, rt: NodeRuntime) -> None:
        """Find a node that is already running (no boot-up will come) by reading 1000h."""
        try:
            device_type = await self.sdo_upload(rt, ObjRef(0x1000, 0), "uint32", check_state=False)
        except Exception:  # noqa: BLE001 - not there yet: wait for its boot-up
            return
        if rt.lifecycle.state == LifecycleState.WAITING:
            log.info("node %s (id %d) found running", rt.name, rt.node_id)
            now = time.monotonic()
            self._apply_changes(rt, rt.lifecycle.on_found(now, device_type))
            if rt.lifecycle.state == LifecycleState.BOOTING:  # not a wrong device type
                if rt.hb is not None and not rt.hb.alive:
                    rt.hb.on_bootup(now)  # monitoring restarts as after a boot-up
                if rt.guard is None or not rt.guard.lost:
                    self._set_alive(rt, True)
                self._start_configuration(rt)

    def _booted(self, rt: NodeRuntime, now: float) -> None:
        """A boot-up message: (re)configure the node from the first step."""
        rt.image.health.boot_count += 1
        if rt.hb is not None:
            rt.hb.on_bootup(now)
        if rt.guard is not None:
            rt.guard.on_bootup(now)  # the toggle bit starts at 0 again (DS-301)
        if rt.gbit is not None:
            rt.gbit.reset()
        rt.emcy.clear()
        rt.image.health.current_errors = []
        self._set_referenced(rt, False)  # MSK5000 5115h: the reference is lost at power-on
        if rt.verify_mapping:
            self._set_pdo_valid(rt, False)  # until the mapping is read back and compared
        if self.passive:
            return
        self._apply_changes(rt, rt.lifecycle.on_bootup(now))
        self._start_configuration(rt)

    def _start_configuration(self, rt: NodeRuntime) -> None:
        old = self._config_tasks.pop(rt.name, None)
        if old is not None:
            old.cancel()
        self._config_tasks[rt.name] = asyncio.create_task(self._configure(rt))

    def _apply_changes(self, rt: NodeRuntime, changes: list[Any]) -> None:
        h = rt.image.health
        for ch in changes:
            if isinstance(ch, StateChanged):
                h.lifecycle = str(ch.new)
                log.info("node %s: %s -> %s (%s)", rt.name, ch.old, ch.new, ch.reason)
            elif isinstance(ch, StepFailed):
                h.last_error = ch.message
                if ch.abort_code is not None:
                    h.last_sdo_abort = ch.abort_code
                log.warning(
                    "node %s: boot step %d failed: %s; retry %d in %.1f s",
                    rt.name, ch.index, ch.message, ch.attempt, ch.retry_in_s,
                )  # fmt: skip
            elif isinstance(ch, StepSkipped):
                log.info("node %s: optional boot step skipped: %s", rt.name, ch.message)
            elif isinstance(ch, BootTimeout):
                h.last_error = rt.lifecycle.last_error or "no boot-up"
                log.warning("node %s (id %d): %s", rt.name, rt.node_id, h.last_error)
            elif isinstance(ch, WrongDevice):
                h.last_error = rt.lifecycle.last_error or "wrong device type"
                log.error("node %s (id %d): %s", rt.name, rt.node_id, h.last_error)
            elif isinstance(ch, Configured):
                h.last_error = ""
                if rt.verify_mapping:
                    self._tasks.append(asyncio.create_task(self._verify_mapping(rt)))
                if rt.referencing is not None:
                    self._tasks.append(asyncio.create_task(self._check_reference(rt)))
                if rt.guard is not None:
                    rt.guard.expect(SupNmt.OPERATIONAL)
                log.info(
                    "node %s (id %d) configured in %.0f ms and started",
                    rt.name, rt.node_id, ch.duration_s * 1000,
                )  # fmt: skip
        if changes:
            self.image.health_changed(rt.image, "state")

    async def _configure(self, rt: NodeRuntime) -> None:
        """Apply the boot configuration step by step (retries with backoff), then NMT start."""
        lc = rt.lifecycle
        while True:
            action = lc.next_action(time.monotonic())
            if action is None:
                return
            if isinstance(action, Wait):
                await asyncio.sleep(action.seconds)
                continue
            if isinstance(action, WriteStep):
                step = action.step
                ok, code = True, None
                try:
                    await self.sdo_download(rt, step.object, step.data, check_state=False)
                except SdoAbort as exc:
                    ok, code = False, exc.code
                except (SdoTimeout, BusDown):
                    ok = False
                except Exception as exc:  # noqa: BLE001 - a failed step must not end the task
                    log.warning("node %s: boot step %s failed: %r", rt.name, step.object, exc)
                    ok = False
                self._apply_changes(
                    rt, lc.on_step_result(time.monotonic(), ok, code, token=action.token)
                )
                continue
            if isinstance(action, SendNmt):
                try:
                    self.driver.send(0x000, bytes([action.command, rt.node_id]))
                except can.CanError:
                    await asyncio.sleep(0.5)
                    continue
                self._apply_changes(rt, lc.on_nmt_sent(time.monotonic()))

    # ------------------------------------------------------------------ control traffic (loop)
    def _on_nmt_ec(self, rt: NodeRuntime, msg: can.Message) -> None:
        if msg.is_remote_frame or not msg.data:
            return
        now = self.driver.frame_time(msg)
        byte = msg.data[0]
        if byte == 0x00:  # boot-up (SGH10 manual 4.2.2)
            log.info("node %s (id %d) boot-up", rt.name, rt.node_id)
            self._set_nmt(rt, NmtState.PRE_OPERATIONAL)
            self._booted(rt, now)
            self._set_alive(rt, True)
            return
        outputs: list[Any]
        if rt.guard is not None:
            outputs = rt.guard.on_response(byte, now)
            state = byte & 0x7F
        elif rt.hb is not None:
            outputs = rt.hb.on_heartbeat(byte, now)
            state = byte
        else:  # no heartbeat consumer (heartbeat_ms 0): take the state as reported
            outputs, state = [], byte & 0x7F
        bad = [o for o in outputs if isinstance(o, (ToggleError, WrongState, InvalidStateByte))]
        for o in bad:
            self.warn.warning(("guard", rt.name, type(o).__name__), "node %s: %s", rt.name, o)
        if not bad:
            self._set_nmt(rt, state)
            self._set_alive(rt, True)
            if rt.lifecycle.state == LifecycleState.WAITING:
                # alive but no boot-up seen (gateway restarted, node replugged): probe + configure
                self._spawn_probe(rt)

    # ------------------------------------------------------------------ verify_mapping
    def _set_pdo_valid(self, rt: NodeRuntime, ok: bool) -> None:
        names = {n for c in (*rt.tpdos, *rt.rpdos) for n in c.names}
        for n in names:
            if ok and n == rt.reference_signal:
                continue  # referencing decides about the position (feature referencing)
            sig = rt.image.signals.get(n)
            if sig is not None:
                sig.valid = ok

    async def _verify_mapping(self, rt: NodeRuntime) -> None:
        """Upload the PDO objects the codecs rely on and compare (gateway.bus.verify)."""
        reads = mapping_reads(rt.lp, rt.node_id, rt.cfg.pdo_variant)
        held: dict[ObjRef, int | None] = {}
        for r in reads:
            try:
                held[r.object] = int(await self.sdo_upload(rt, r.object, r.type, check_state=False))
            except (SdoAbort, SdoTimeout, BusDown, ValueError, TypeError):
                held[r.object] = None
        rt.mapping_mismatches = compare_mapping(reads, held)
        if rt.mapping_mismatches:
            text = "; ".join(str(m) for m in rt.mapping_mismatches)
            rt.image.health.last_error = f"PDO mapping mismatch, values not served: {text}"
            self._set_pdo_valid(rt, False)
            log.error("node %s: PDO mapping mismatch, values not served: %s", rt.name, text)
        else:
            self._set_pdo_valid(rt, True)
            log.info("node %s: PDO mapping verified (%d objects read back)", rt.name, len(reads))
        self.image.health_changed(rt.image, "state")

    # ------------------------------------------------------------------ referencing (feature)
    def _set_referenced(self, rt: NodeRuntime, ok: bool) -> None:
        """Feature ``referencing`` (MSK5000 5115h): no valid position before referencing."""
        if rt.referencing is None or rt.reference_signal is None:
            return
        sig = rt.image.signals.get(rt.reference_signal)
        if sig is not None and sig.valid != ok:
            sig.valid = ok
            if not ok:
                log.warning("node %s: not referenced; %s is not valid", rt.name, rt.reference_signal)
            else:
                log.info("node %s: referenced; %s valid", rt.name, rt.reference_signal)
            self.image.health_changed(rt.image, "state")

    async def _check_reference(self, rt: NodeRuntime) -> None:
        ref = rt.referencing
        assert ref is not None
        try:
            value = await self.sdo_upload(rt, ObjRef.parse(ref["status"]), "uint8", check_state=False)
        except (SdoAbort, SdoTimeout, BusDown) as exc:
            log.warning("node %s: referencing state unreadable: %s", rt.name, exc)
            self._set_referenced(rt, False)
            return
        self._set_referenced(rt, int(value) == int(ref.get("referenced_value", 1)))

    def _set_nmt(self, rt: NodeRuntime, state: int) -> None:
        try:
            st = NmtState(state)
        except ValueError:
            st = NmtState.UNKNOWN
        if rt.image.health.nmt_state != st:
            rt.image.health.nmt_state = st
            log.info("node %s NMT state %s", rt.name, st.name)
            self.image.health_changed(rt.image, "state")

    def _set_alive(self, rt: NodeRuntime, alive: bool) -> None:
        h = rt.image.health
        if h.alive == alive:
            return
        h.alive = alive
        if not alive:
            h.loss_count += 1
            if rt.gbit is not None:
                rt.gbit.reset()
                self._update_link(rt)
            self._apply_changes(rt, rt.lifecycle.on_lost(time.monotonic()))
            log.warning("node %s (id %d) lost (%s)", rt.name, rt.node_id, rt.supervision)
        else:
            log.info("node %s (id %d) alive", rt.name, rt.node_id)
        self.image.health_changed(rt.image, "state")

    def _on_emcy(self, rt: NodeRuntime, msg: can.Message) -> None:
        if len(msg.data) < 3:
            rt.image.health.pdo_errors += 1
            return
        rec = decode_emcy(bytes(msg.data), rt.lp.profile.emcy, msg.timestamp or time.time())
        rt.emcy.add(rec)
        h = rt.image.health
        h.last_emcy = rec
        h.emcy_count += 1
        h.current_errors = sorted(rt.emcy.current)
        log.warning(
            "node %s EMCY 0x%04X (%s) register 0x%02X", rt.name, rec.code, rec.text, rec.register
        )
        self.image.health_changed(rt.image, "emcy")
        if rt.referencing is not None and self.loop is not None:
            self._tasks.append(asyncio.create_task(self._check_reference(rt)))

    def _on_guarding_echo(self, rt: NodeRuntime, bit: int) -> None:
        if rt.gbit is None:
            return
        rt.gbit.on_status(bit, time.monotonic())
        self._update_link(rt)

    def _update_link(self, rt: NodeRuntime) -> None:
        if rt.gbit is None:
            return
        state = {"ok": LinkState.OK, "fault": LinkState.FAULT}.get(rt.gbit.state, LinkState.UNKNOWN)
        h = rt.image.health
        if h.link != state:
            if state == LinkState.FAULT:
                h.link_fault_count += 1
                log.warning("node %s: guarding-bit link FAULT (process data not echoed)", rt.name)
            elif h.link == LinkState.FAULT:
                log.info("node %s: guarding-bit link restored", rt.name)
            h.link = state
            self.image.health_changed(rt.image, "state")

    # ------------------------------------------------------------------ periodic tasks
    async def _supervise(self) -> None:
        tick = 0.01
        while True:
            await asyncio.sleep(tick)
            now = time.monotonic()
            bus_now = self.driver.bus_clock()  # supervision judges by the frames processed
            for rt in self.nodes.values():
                self._poll_node(rt, now, bus_now)
                if (
                    rt.lifecycle.state == LifecycleState.WAITING
                    and rt.next_probe_s is not None
                    and now >= rt.next_probe_s
                ):
                    # a node whose boot-up was missed and that sends no heartbeat (1017h = 0)
                    self._spawn_probe(rt)

    def _poll_node(self, rt: NodeRuntime, now: float, bus_now: float | None = None) -> None:
        bus_now = now if bus_now is None else bus_now
        if rt.guard is not None:
            for out in rt.guard.poll(bus_now):
                if isinstance(out, SendGuardRtr):
                    try:
                        self.driver.send(0x700 + rt.node_id, b"", rtr=True, dlc=1)
                    except can.CanError:
                        pass
            if rt.guard.lost and rt.image.health.alive:
                self._set_alive(rt, False)
        elif rt.supervision == "heartbeat" and rt.hb is not None:
            rt.hb.poll(bus_now)
            if rt.hb.lost and rt.image.health.alive:
                self._set_alive(rt, False)
        changes = rt.lifecycle.poll(now)
        if changes:
            self._apply_changes(rt, changes)
        if rt.gbit is not None:
            rt.gbit.poll(now)
            self._update_link(rt)
        if rt.keepalive_s and rt.rpdos and rt.image.health.alive:
            # Keep-alive: re-send the last RPDO when none went out for keepalive_s, to feed the
            # AP05 external heartbeat (source RPDO, manual 5.5.4) and to exercise the guarding
            # bit (manual 5.5.5) when the PLC writes nothing. Only in OPERATIONAL (RPDOs are
            # not processed otherwise).
            last = max(rt.last_rpdo_sent.values(), default=0.0)
            if (
                now - last >= rt.keepalive_s
                and rt.image.health.nmt_state == NmtState.OPERATIONAL
            ):
                number = max(rt.last_rpdo_sent, key=rt.last_rpdo_sent.get, default=None)
                codec = next((c for c in rt.rpdos if c.number == number), rt.rpdos[-1])
                try:
                    self.send_rpdo(rt, codec)
                except (BusDown, NodeNotOperational):
                    pass

    async def _heartbeat_producer(self) -> None:
        period = self.cfg.master.heartbeat_ms / 1000.0
        cob = 0x700 + self.cfg.master.node_id
        while True:
            try:
                self.driver.send(cob, b"\x05")
            except can.CanError:
                pass
            await asyncio.sleep(period)

    async def _sync_producer(self) -> None:
        period = self.cfg.master.sync_period_ms / 1000.0
        nxt = time.monotonic()
        while True:
            try:
                self.driver.send(0x080, b"")
            except can.CanError:
                pass
            nxt += period
            delay = nxt - time.monotonic()
            if delay < 0:
                nxt = time.monotonic()
                delay = 0
            await asyncio.sleep(delay)

    async def _rtr_poll(self, rt: NodeRuntime) -> None:
        assert rt.cfg.rtr_poll_ms
        while True:
            await asyncio.sleep(rt.cfg.rtr_poll_ms / 1000.0)
            if rt.image.health.nmt_state != NmtState.OPERATIONAL:
                continue
            for codec in rt.tpdos:
                try:
                    self.driver.send(codec.cob_id, b"", rtr=True, dlc=codec.length)
                except can.CanError:
                    pass

    # ------------------------------------------------------------------ services
    def _require_bus(self) -> None:
        if self.driver.state == "down":
            raise BusDown(self.driver.last_error or "CAN bus is down")

    def nmt_send(self, node_id: int, command: str) -> None:
        """NMT command to a node id (0 = all nodes)."""
        self._require_bus()
        try:
            self.driver.send(0x000, bytes([NMT_COMMANDS[command], node_id]))
        except can.CanError as exc:
            raise BusDown(str(exc)) from exc

    def send_rpdo(self, rt: NodeRuntime, codec: RpdoCodec) -> None:
        self._require_bus()
        if rt.gbit is not None and rt.guarding_bit is not None:
            cw_sig = rt.lp.profile.signal_for(ObjRef.parse(rt.guarding_bit["control"]))
            if cw_sig is not None and cw_sig.name in codec.names:
                bit = int(rt.guarding_bit.get("control_bit", 8))
                cw = int(codec.get(cw_sig.name)) & ~(1 << bit)
                cw |= rt.gbit.next_bit(time.monotonic()) << bit
                codec.set(cw_sig.name, cw)
        try:
            data = codec.encode()
            self.driver.send(codec.cob_id, data)
        except can.CanError as exc:
            raise BusDown(str(exc)) from exc
        rt.last_rpdo_sent[codec.number] = time.monotonic()
        rt.image.health.rpdo_sent += 1
        for listener in self.image.pdo_listeners:
            listener(rt.image, codec.cob_id, data)
        for hook in self.rpdo_hooks:
            hook(rt, codec)

    def _od_type(self, rt: NodeRuntime, obj: ObjRef) -> str | None:
        sig = rt.lp.profile.signal_for(obj)
        if sig is not None:
            return sig.type
        var = rt.lp.od_var(obj)
        if var is None:
            return None
        return OD_TYPE_NAMES.get(var.data_type)

    async def sdo_upload(
        self, rt: NodeRuntime, obj: ObjRef, type_: str | None = None, check_state: bool = True
    ) -> Any:
        """Read an object by SDO; returns the decoded value (bytes when the type is unknown)."""
        self._require_bus()
        if check_state and not rt.image.health.alive:
            raise NodeNotOperational(rt.name, "not alive")
        async with rt.sdo_lock:
            try:
                data = await asyncio.to_thread(rt.remote.sdo.upload, obj.index, obj.sub)
            except SdoAbortedError as exc:
                rt.image.health.last_sdo_abort = exc.code
                raise SdoAbort(exc.code, node=rt.name, obj=str(obj)) from None
            except SdoCommunicationError as exc:
                raise SdoTimeout(rt.name, str(obj), str(exc)) from None
            except can.CanError as exc:
                raise BusDown(str(exc)) from None
        t = type_ or self._od_type(rt, obj)
        return data if t is None else decode_value(bytes(data), t)

    async def sdo_download(
        self,
        rt: NodeRuntime,
        obj: ObjRef,
        value: Any,
        type_: str | None = None,
        check_state: bool = True,
    ) -> None:
        self._require_bus()
        if check_state and not rt.image.health.alive:
            raise NodeNotOperational(rt.name, "not alive")
        if isinstance(value, (bytes, bytearray)):
            data = bytes(value)
        else:
            t = type_ or self._od_type(rt, obj)
            if t is None:
                raise ValueError(f"type of {obj} unknown; give a type")
            if isinstance(value, str) and t not in ("string", "bytes"):
                value = float(value) if t == "float32" else int(value, 0)
            data = encode_value(value, t)
        async with rt.sdo_lock:
            try:
                await asyncio.to_thread(rt.remote.sdo.download, obj.index, obj.sub, data)
            except SdoAbortedError as exc:
                rt.image.health.last_sdo_abort = exc.code
                raise SdoAbort(exc.code, node=rt.name, obj=str(obj)) from None
            except SdoCommunicationError as exc:
                raise SdoTimeout(rt.name, str(obj), str(exc)) from None
            except can.CanError as exc:
                raise BusDown(str(exc)) from None
        if rt.referencing is not None and obj == ObjRef.parse(rt.referencing["command"]):
            self._tasks.append(asyncio.create_task(self._check_reference(rt)))
