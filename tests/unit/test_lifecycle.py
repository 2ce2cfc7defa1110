"""Node lifecycle machine with a fake clock, and the boot step builder against the manuals.

The remapping sequence is checked frame by frame against the MSK5000 manual 4.3.1.2 example
(frames copied here as data). The SDO abort texts used in step errors are checked too.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest

from canopen_gateway.bus.node.lifecycle import (
    RECHECK_BACKOFF,
    Backoff,
    BootTimeout,
    Configured,
    IdentityNotCompared,
    LifecycleState,
    NodeLifecycle,
    SendNmt,
    StateChanged,
    StepFailed,
    StepSkipped,
    Wait,
    WriteStep,
    WrongDevice,
)
from canopen_gateway.canopen.cia301 import SDO_ABORT_TEXTS, abort_text
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.device.boot_steps import ConfigStep, build_boot_steps
from canopen_gateway.device.values import encode_value
from canopen_gateway.errors import SdoAbort
from canopen_gateway.profiles import (
    ExternalHeartbeatSetup,
    LoadedProfile,
    NodeSetup,
    SdoSetup,
    load_profile,
)
from canopen_gateway.profiles.schema import BootWrite, Pdo

W = LifecycleState.WAITING
B = LifecycleState.BOOTING
C = LifecycleState.CONFIGURING
O = LifecycleState.OPERATIONAL  # noqa: E741

STEPS = [
    ConfigStep(ObjRef(0x1017, 0), 100, "uint16", "producer heartbeat time"),
    ConfigStep(ObjRef(0x1800, 2), 254, "uint8", "TPDO1 transmission type"),
    ConfigStep(ObjRef(0x1800, 5), 10, "uint16", "TPDO1 event timer"),
]


def just_after(t: float) -> float:
    return math.nextafter(t, math.inf)


def states(changes: list[object]) -> list[tuple[LifecycleState, LifecycleState]]:
    return [(c.old, c.new) for c in changes if isinstance(c, StateChanged)]


def run_all_steps(lc: NodeLifecycle, now: float) -> None:
    while True:
        a = lc.next_action(now)
        if not isinstance(a, WriteStep):
            break
        lc.on_step_result(now, ok=True, token=a.token)


# --------------------------------------------------------------------------- the machine


class TestBootAndConfigure:
    def test_boot_up_starts_configuration_with_first_step(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.start(0.0)
        out = lc.on_bootup(1.0)
        assert states(out) == [(W, B), (B, C)]
        a = lc.next_action(1.0)
        assert isinstance(a, WriteStep) and a.kind == "sdo"
        assert (a.index, a.step) == (0, STEPS[0])
        assert lc.boots == 1

    def test_steps_go_in_order_then_nmt_start_then_operational(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        seen = []
        for i in range(len(STEPS)):
            a = lc.next_action(0.1 * i)
            assert isinstance(a, WriteStep)
            seen.append(a.step.object)
            assert lc.on_step_result(0.1 * i, ok=True, token=a.token) == []
        assert seen == [s.object for s in STEPS]
        assert lc.next_action(0.5) == SendNmt("nmt_start", 0x01)
        assert lc.state is C  # not operational before the start went out
        out = lc.on_nmt_sent(0.5)
        assert states(out) == [(C, O)]
        assert Configured(duration_s=0.5) in out
        assert lc.next_action(0.6) is None
        assert lc.configurations == 1 and lc.last_error is None

    def test_same_step_is_handed_out_until_its_result_arrives(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        a1 = lc.next_action(0.0)
        a2 = lc.next_action(0.01)
        assert a1 == a2

    def test_without_steps_the_node_is_started_at_once(self) -> None:
        lc = NodeLifecycle([])
        lc.on_bootup(0.0)
        assert lc.next_action(0.0) == SendNmt("nmt_start", 0x01)

    def test_nothing_to_do_while_waiting(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.start(0.0)
        assert lc.next_action(0.0) is None
        assert lc.on_step_result(0.0, ok=True) == []
        assert lc.on_nmt_sent(0.0) == []


class TestBootUpDuringConfiguration:
    def test_boot_up_while_configuring_restarts_at_step_zero(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        lc.on_step_result(0.0, ok=True, token=a.token)
        old = lc.next_action(0.1)  # step 1 in flight
        assert isinstance(old, WriteStep) and old.index == 1
        out = lc.on_bootup(0.2)
        assert states(out) == [(C, B), (B, C)]
        new = lc.next_action(0.2)
        assert isinstance(new, WriteStep) and new.index == 0
        assert lc.boots == 2

    def test_result_from_before_the_boot_up_is_ignored(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        old = lc.next_action(0.0)
        assert isinstance(old, WriteStep)
        lc.on_bootup(0.1)
        new = lc.next_action(0.1)
        assert isinstance(new, WriteStep) and new.token != old.token
        assert lc.on_step_result(0.15, ok=False, abort_code=0x08000022, token=old.token) == []
        assert lc.step_index == 0 and lc.step_failures == 0
        lc.on_step_result(0.2, ok=True, token=new.token)
        assert lc.step_index == 1

    def test_boot_up_while_operational_reconfigures(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        run_all_steps(lc, 0.0)
        lc.on_nmt_sent(0.0)
        assert lc.state is O
        out = lc.on_bootup(5.0)
        assert states(out) == [(O, B), (B, C)]
        a = lc.next_action(5.0)
        assert isinstance(a, WriteStep) and a.index == 0


class TestRetryBackoff:
    def test_failed_step_reports_object_and_abort_code_and_waits(self) -> None:
        lc = NodeLifecycle(STEPS, backoff=Backoff(initial_s=0.5, factor=2.0, max_s=4.0))
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        out = lc.on_step_result(1.0, ok=False, abort_code=0x06090030, token=a.token)
        assert len(out) == 1 and isinstance(out[0], StepFailed)
        f = out[0]
        assert (f.index, f.step.object, f.abort_code, f.attempt) == (
            0,
            ObjRef(0x1017, 0),
            0x06090030,
            1,
        )
        assert f.retry_in_s == 0.5
        assert "0x1017:00" in f.message and "0x06090030" in f.message
        assert "Invalid value for parameter" in f.message
        assert lc.last_error == f.message

    def test_retry_is_due_exactly_at_backoff_time(self) -> None:
        lc = NodeLifecycle(STEPS, backoff=Backoff(initial_s=0.5, factor=2.0, max_s=4.0))
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        lc.on_step_result(1.0, ok=False, abort_code=None, token=a.token)  # timeout
        retry_at = lc.retry_at_s
        assert retry_at == 1.5
        before = lc.next_action(1.25)
        assert before == Wait("wait", 0.25)
        assert isinstance(lc.next_action(math.nextafter(retry_at, 0.0)), Wait)
        again = lc.next_action(retry_at)
        assert isinstance(again, WriteStep) and again.index == 0 and again.token != a.token

    def test_backoff_doubles_and_is_capped(self) -> None:
        lc = NodeLifecycle(STEPS, backoff=Backoff(initial_s=0.5, factor=2.0, max_s=3.0))
        lc.on_bootup(0.0)
        now = 0.0
        delays = []
        for _ in range(5):
            a = lc.next_action(now)
            assert isinstance(a, WriteStep)
            (f,) = lc.on_step_result(now, ok=False, abort_code=None, token=a.token)
            assert isinstance(f, StepFailed)
            delays.append(f.retry_in_s)
            now = lc.retry_at_s or now
        assert delays == [0.5, 1.0, 2.0, 3.0, 3.0]
        assert lc.attempt == 5 and lc.step_failures == 5

    def test_success_after_failures_resets_the_attempt_count(self) -> None:
        lc = NodeLifecycle(STEPS, backoff=Backoff(initial_s=0.5))
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        lc.on_step_result(0.0, ok=False, token=a.token)
        a = lc.next_action(0.5)
        assert isinstance(a, WriteStep)
        lc.on_step_result(0.5, ok=True, token=a.token)
        assert lc.attempt == 0 and lc.step_index == 1
        a = lc.next_action(0.5)
        assert isinstance(a, WriteStep)
        (f,) = lc.on_step_result(0.6, ok=False, token=a.token)
        assert isinstance(f, StepFailed) and f.attempt == 1 and f.retry_in_s == 0.5

    def test_optional_step_refused_by_device_is_skipped(self) -> None:
        steps = [
            ConfigStep(ObjRef(0x5FFA, 0), 100, "uint16", "speed alarm", optional=True),
            STEPS[0],
        ]
        lc = NodeLifecycle(steps)
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        out = lc.on_step_result(0.0, ok=False, abort_code=0x06020000, token=a.token)
        assert len(out) == 1 and isinstance(out[0], StepSkipped)
        nxt = lc.next_action(0.0)
        assert isinstance(nxt, WriteStep) and nxt.index == 1

    def test_optional_step_without_answer_is_retried(self) -> None:
        steps = [ConfigStep(ObjRef(0x5FFA, 0), 100, "uint16", "speed alarm", optional=True)]
        lc = NodeLifecycle(steps)
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        (f,) = lc.on_step_result(0.0, ok=False, abort_code=None, token=a.token)
        assert isinstance(f, StepFailed)


class TestFoundRunningAndLost:
    def test_found_running_goes_pre_operational_before_configuring(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.start(0.0)
        out = lc.on_found(0.5, device_type=0x000A0196)
        assert states(out) == [(W, B)]
        assert lc.next_action(0.5) == SendNmt("nmt_preop", 0x80)
        assert lc.next_action(0.6) == SendNmt("nmt_preop", 0x80)  # until reported sent
        out = lc.on_nmt_sent(0.6)
        assert states(out) == [(B, C)]
        a = lc.next_action(0.6)
        assert isinstance(a, WriteStep) and a.index == 0
        assert lc.boots == 0

    def test_found_with_another_device_type_is_not_configured(self) -> None:
        lc = NodeLifecycle(STEPS, expected_device_type=0x000A0196)
        lc.start(0.0)
        out = lc.on_found(0.5, device_type=0x00020196)
        assert out == [WrongDevice(expected=0x000A0196, found=0x00020196, recheck_in_s=60.0)]
        assert lc.state is W and lc.next_action(0.5) is None
        assert lc.last_error is not None and "0x00020196" in lc.last_error
        assert lc.poll(100.0) == []  # it did appear: no boot timeout on top

    def test_found_is_ignored_unless_waiting(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        assert lc.on_found(0.1) == []
        assert lc.state is C

    def test_lost_returns_to_waiting_from_any_state(self) -> None:
        for setup in ("configuring", "operational", "booting"):
            lc = NodeLifecycle(STEPS)
            lc.start(0.0)
            if setup == "booting":
                lc.on_found(0.0)
            else:
                lc.on_bootup(0.0)
            if setup == "operational":
                run_all_steps(lc, 0.0)
                lc.on_nmt_sent(0.0)
            old = lc.state
            out = lc.on_lost(1.0)
            assert states(out) == [(old, W)]
            assert lc.state is W and lc.losses == 1
            assert lc.next_action(1.0) is None

    def test_lost_while_waiting_changes_nothing(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.start(0.0)
        assert lc.on_lost(1.0) == []
        assert lc.losses == 0

    def test_step_result_after_loss_is_ignored(self) -> None:
        lc = NodeLifecycle(STEPS)
        lc.on_bootup(0.0)
        a = lc.next_action(0.0)
        assert isinstance(a, WriteStep)
        lc.on_lost(0.1)
        assert lc.on_step_result(0.2, ok=True, token=a.token) == []
        assert lc.state is W


class TestBootTimeout:
    def test_boot_timeout_fires_just_after_deadline_once(self) -> None:
        lc = NodeLifecycle(STEPS, boot_timeout_s=10.0)
        lc.start(3.0)
        deadline = lc.boot_deadline_s
        assert deadline == 13.0
        assert lc.poll(deadline) == []
        out = lc.poll(just_after(deadline))
        assert len(out) == 1 and isinstance(out[0], BootTimeout)
        assert out[0].waited_s == pytest.approx(10.0)
        assert lc.state is W
        assert lc.poll(100.0) == []
        assert lc.last_error is not None and "10 s" in lc.last_error

    def test_boot_up_before_deadline_disarms_timeout(self) -> None:
        lc = NodeLifecycle(STEPS, boot_timeout_s=10.0)
        lc.start(0.0)
        lc.on_bootup(5.0)
        assert lc.poll(20.0) == []

    def test_timeout_is_armed_again_after_a_loss(self) -> None:
        lc = NodeLifecycle(STEPS, boot_timeout_s=2.0)
        lc.start(0.0)
        lc.on_bootup(1.0)
        lc.on_lost(5.0)
        assert lc.poll(7.0) == []
        assert kinds(lc.poll(just_after(7.0))) == [BootTimeout]

    def test_next_deadline_is_boot_timeout_or_retry(self) -> None:
        lc = NodeLifecycle(STEPS, boot_timeout_s=2.0, backoff=Backoff(initial_s=0.25))
        lc.start(0.0)
        assert lc.next_deadline() == 2.0
        lc.on_bootup(1.0)
        assert lc.next_deadline() is None
        a = lc.next_action(1.0)
        assert isinstance(a, WriteStep)
        lc.on_step_result(1.0, ok=False, token=a.token)
        assert lc.next_deadline() == 1.25


def kinds(outputs: list[object]) -> list[type]:
    return [type(o) for o in outputs]


# --------------------------------------------------------------------------- steps and values


class TestStepEncoding:
    def test_values_are_little_endian_with_the_type_size(self) -> None:
        assert ConfigStep(ObjRef(0x1017, 0), 100, "uint16").data == b"\x64\x00"
        assert ConfigStep(ObjRef(0x100D, 0), 3, "uint8").data == b"\x03"
        assert ConfigStep(ObjRef(0x1800, 1), 0x80000181, "uint32").data == bytes.fromhex("81010080")
        assert encode_value(-2, "int32") == b"\xfe\xff\xff\xff"
        assert encode_value(0x123456, "uint24") == b"\x56\x34\x12"
        assert encode_value("AB", "string") == b"AB"

    def test_value_that_does_not_fit_is_rejected(self) -> None:
        with pytest.raises(ValueError, match="does not fit uint8"):
            encode_value(256, "uint8")


# --------------------------------------------------------------------------- builder


def node(node_id: int = 1, **kw: Any) -> NodeSetup:
    return NodeSetup(node_id=node_id, **kw)


def with_tpdos(
    lp: LoadedProfile, tpdos: list[Pdo], boot_sdo: list[BootWrite] | None = None
) -> LoadedProfile:
    boot = lp.profile.boot.model_copy(update={"sdo": boot_sdo or []})
    profile = lp.profile.model_copy(update={"tpdos": tpdos, "boot": boot})
    return LoadedProfile(profile, lp.path, lp.eds_path, lp.od)


def sdo_download_frame(step: ConfigStep) -> bytes:
    """DS-301 expedited download request (SGH10 manual 4.4.1.1): 23h/27h/2Bh/2Fh by size."""
    data = step.data
    assert 1 <= len(data) <= 4
    cmd = 0x23 | ((4 - len(data)) << 2)
    return struct.pack("<BHB", cmd, step.object.index, step.object.sub) + data.ljust(4, b"\0")


MSK5000_EXAMPLE_MAPPING = ["0x6004:00/32", "0x5122:01/8", "0x5122:02/8"]

# MSK5000 manual 4.3.1.2, example with node id 1, frames on 601h (SDO rx).
MSK5000_EXAMPLE_FRAMES = [
    "23 00 18 01 81 01 00 80",  # TPDO1 off: COB-ID 80000181h
    "23 00 1A 00 00 00 00 00",  # 1A00h:00 = 0
    "23 00 1A 01 20 00 04 60",  # 6004h:00, 32 bit
    "23 00 1A 02 08 01 22 51",  # 5122h:01, 8 bit
    "23 00 1A 03 08 02 22 51",  # 5122h:02, 8 bit
    "23 00 1A 00 03 00 00 00",  # 1A00h:00 = 3
    "23 00 18 01 81 01 00 00",  # TPDO1 on: COB-ID 00000181h
]


class TestBuildBootSteps:
    @pytest.mark.parametrize("family", ["sgh10", "ap05", "msk5000", "posi_plus", "posi_sf"])
    def test_every_builtin_profile_builds_steps_that_end_with_its_boot_writes(
        self, family: str
    ) -> None:
        lp = load_profile(family)
        steps = build_boot_steps(lp, node(5))
        assert steps[0] == ConfigStep(
            ObjRef(0x1017, 0),
            lp.profile.boot.heartbeat_ms,
            "uint16",
            "producer heartbeat time (ms)",
        )
        boot_objs = [w.object for w in lp.profile.boot.sdo]
        assert [s.object for s in steps[-len(boot_objs) :]] == boot_objs
        for s in steps:
            var = lp.od_var(s.object)
            assert var is not None and var.writable, s

    def test_msk5000_remapping_follows_manual_sequence_frame_by_frame(self) -> None:
        lp = load_profile("msk5000")
        pdo = Pdo(number=1, cob_id=0x180, transmission_type=254, mapping=MSK5000_EXAMPLE_MAPPING)
        steps = build_boot_steps(with_tpdos(lp, [pdo]), node(1))
        remap = [s for s in steps if s.object.index in (0x1A00,) or s.object == ObjRef(0x1800, 1)]
        frames = [sdo_download_frame(s) for s in remap]
        expected = [bytes.fromhex(f) for f in MSK5000_EXAMPLE_FRAMES]
        assert len(frames) == len(expected)
        for got, want in zip(frames, expected, strict=True):
            if want[1:4] == bytes.fromhex("001A00"):
                # 1A00h:00 is UNSIGNED8 (manual 4.6.1.20, EDS): one data byte, command 2Fh
                # where the example prints 23h; same object, same value.
                assert got[0] == 0x2F and got[1:5] == want[1:5]
            else:
                assert got == want

    def test_msk5000_remapping_comes_after_supervision_and_before_boot_writes(self) -> None:
        lp = load_profile("msk5000")
        steps = build_boot_steps(lp, node(3))
        objs = [s.object for s in steps]
        first_cob = objs.index(ObjRef(0x1800, 1))
        assert objs[0] == ObjRef(0x1017, 0)
        assert steps[first_cob].value == 0x80000183
        assert steps[objs.index(ObjRef(0x1801, 1))].value == 0x80000283
        last_cob = len(objs) - 1 - objs[::-1].index(ObjRef(0x1801, 1))
        assert steps[last_cob].value == 0x283
        boot = [w.object for w in lp.profile.boot.sdo]
        assert objs[last_cob + 1 :] == boot

    def test_profiles_without_remapping_do_not_touch_cob_ids_or_mappings(self) -> None:
        steps = build_boot_steps(load_profile("sgh10"), node(1))
        assert not [s for s in steps if s.object.sub == 1 and s.object.index in (0x1800, 0x1801)]
        assert not [s for s in steps if 0x1A00 <= s.object.index <= 0x1BFF]

    def test_guarding_disables_heartbeat_and_sets_guard_time_and_factor(self) -> None:
        steps = build_boot_steps(load_profile("sgh10"), node(1, supervision="guarding", guard_time_ms=250, life_time_factor=4))
        assert [(s.object, s.value, s.type) for s in steps[:3]] == [
            (ObjRef(0x1017, 0), 0, "uint16"),
            (ObjRef(0x100C, 0), 250, "uint16"),
            (ObjRef(0x100D, 0), 4, "uint8"),
        ]

    def test_no_supervision_writes_no_supervision_objects(self) -> None:
        steps = build_boot_steps(load_profile("sgh10"), node(1, supervision="none"))
        assert not [s for s in steps if s.object.index in (0x1017, 0x100C, 0x100D)]

    def test_heartbeat_time_from_node_settings(self) -> None:
        steps = build_boot_steps(load_profile("sgh10"), node(1, supervision="heartbeat", heartbeat_ms=250))
        assert steps[0].object == ObjRef(0x1017, 0) and steps[0].value == 250

    def test_tpdo_transmission_type_and_event_timer_from_layout(self) -> None:
        lp = load_profile("sgh10")
        pdo = Pdo(number=1, transmission_type=1, event_timer_ms=50, mapping=["0x6020:01/32"])
        steps = build_boot_steps(with_tpdos(lp, [pdo]), node(1))
        assert [(s.object, s.value) for s in steps[1:]] == [
            (ObjRef(0x1800, 2), 1),
            (ObjRef(0x1800, 5), 50),
        ]

    def test_read_only_object_already_at_wanted_value_is_skipped(self) -> None:
        lp = load_profile("sgh10")  # 1801h:05 is ro (event timer not supported on TPDO2)
        pdo = Pdo(number=2, transmission_type=1, event_timer_ms=0, mapping=["0x6020:01/32"])
        steps = build_boot_steps(with_tpdos(lp, [pdo]), node(1))
        assert ObjRef(0x1801, 5) not in [s.object for s in steps]

    def test_read_only_object_the_profile_wants_changed_is_an_error(self) -> None:
        lp = load_profile("sgh10")
        pdo = Pdo(number=2, transmission_type=1, event_timer_ms=100, mapping=["0x6020:01/32"])
        with pytest.raises(ValueError, match=r"0x1801:05 is read-only"):
            build_boot_steps(with_tpdos(lp, [pdo]), node(1))

    def test_non_default_inhibit_time_is_written_with_pdo_disabled(self) -> None:
        lp = load_profile("posi_sf")  # 1800h:03 rw
        pdo = Pdo(number=1, transmission_type=254, inhibit_time_100us=50, mapping=["0x6004:00/32"])
        steps = build_boot_steps(with_tpdos(lp, [pdo]), node(2))
        tail = [
            (s.object, s.value)
            for s in steps
            if s.object.index == 0x1800 and s.object.sub in (1, 3)
        ]
        assert tail == [
            (ObjRef(0x1800, 1), 0x80000182),
            (ObjRef(0x1800, 3), 50),
            (ObjRef(0x1800, 1), 0x182),
        ]

    def test_explicit_writes_override_derived_ones_and_keep_order(self) -> None:
        lp = load_profile("sgh10")
        extra = (
            SdoSetup(ObjRef(0x1017, 0), 500),
            SdoSetup(ObjRef(0x6200, 0), "0x14"),
        )
        steps = build_boot_steps(lp, node(1, sdo=extra))
        objs = [s.object for s in steps]
        assert objs.count(ObjRef(0x1017, 0)) == 1
        assert steps[-2:] == [
            ConfigStep(ObjRef(0x1017, 0), 500, "uint16", "node sdo[0]"),
            ConfigStep(ObjRef(0x6200, 0), 20, "uint16", "node sdo[1]"),
        ]

    def test_signature_text_is_sent_as_its_ascii_bytes(self) -> None:
        lp = load_profile("posi_plus")
        extra = (SdoSetup(ObjRef(0x1010, 1), "save"),)
        (step,) = build_boot_steps(lp, node(1, sdo=extra))[-1:]
        assert step.value == 0x65766173  # "save", BEI manual 1010h
        assert step.data == b"save"

    def test_write_to_missing_object_names_it(self) -> None:
        extra = (SdoSetup(ObjRef(0x1234, 7), 1),)
        with pytest.raises(ValueError, match=r"node sdo\[0\]: 0x1234:07 is not in sgh10.eds"):
            build_boot_steps(load_profile("sgh10"), node(1, sdo=extra))

    def test_write_to_read_only_object_names_it(self) -> None:
        extra = (SdoSetup(ObjRef(0x1000, 0), 1),)
        with pytest.raises(ValueError, match=r"node sdo\[0\]: 0x1000:00 is read-only"):
            build_boot_steps(load_profile("sgh10"), node(1, sdo=extra))

    def test_pdo_variant_selector_is_written_before_the_tpdos(self) -> None:
        lp = load_profile("posi_plus")
        steps = build_boot_steps(lp, node(1, pdo_variant=2))
        objs = [s.object for s in steps]
        sel = lp.profile.pdo_variants.selector  # type: ignore[union-attr]
        assert steps[objs.index(sel)].value == 2
        assert objs.index(sel) < objs.index(ObjRef(0x1800, 2))

    def test_external_heartbeat_source_then_interval(self) -> None:
        lp = load_profile("ap05")
        ext = ExternalHeartbeatSetup(interval_ms=200, source="rpdo")
        steps = build_boot_steps(lp, node(125, external_heartbeat=ext))
        assert [(s.object, s.value) for s in steps[1:3]] == [
            (ObjRef(0x5F09, 2), 0),  # AP05 manual 5F09h:02: 0 = triggered by an RPDO
            (ObjRef(0x5F09, 1), 200),
        ]

    def test_external_heartbeat_needs_the_feature(self) -> None:
        ext = ExternalHeartbeatSetup(interval_ms=200, source="rpdo")
        with pytest.raises(ValueError, match="no feature external_heartbeat"):
            build_boot_steps(load_profile("sgh10"), node(1, external_heartbeat=ext))


# --------------------------------------------------------------------------- SDO abort texts


class TestSdoAbortTexts:
    def test_table_covers_ds301_codes_from_toggle_to_no_data(self) -> None:
        assert min(SDO_ABORT_TEXTS) == 0x05030000
        assert max(SDO_ABORT_TEXTS) == 0x08000024
        # SGH10 manual 4.4.1.3 table 8: every code the device uses has a text
        for code in (
            0x05030000,
            0x06010000,
            0x06010001,
            0x06010002,
            0x06020000,
            0x06090011,
            0x06090030,
            0x08000020,
            0x08000022,
            0x08000024,
        ):
            assert code in SDO_ABORT_TEXTS

    def test_unknown_code_is_worded_as_such(self) -> None:
        assert "not a DS-301 abort code" in abort_text(0x12345678)

    def test_sdo_abort_error_reads_with_code_text_object_and_node(self) -> None:
        e = SdoAbort(0x06090011, node=3, obj=ObjRef(0x6004, 5))
        assert str(e) == "SDO abort 0x06090011 (Sub-index does not exist) at 0x6004:05 on node 3"
        assert (e.code, e.text) == (0x06090011, "Sub-index does not exist")


# --------------------------------------------------------------------------- identity (1018h)

IDENTITY = ((ObjRef(0x1018, 1), 0x195), (ObjRef(0x1018, 2), 0x401))


def _read(lc: NodeLifecycle, now: float) -> Any:
    from canopen_gateway.bus.node.lifecycle import ReadIdentity

    a = lc.next_action(now)
    assert isinstance(a, ReadIdentity), a
    return a


def test_identity_is_read_before_the_first_step_and_a_match_configures() -> None:
    step = ConfigStep(ObjRef(0x1017, 0), 100, "uint16", "heartbeat")
    lc = NodeLifecycle([step], expected_identity=IDENTITY)
    lc.on_bootup(0.0)
    a = _read(lc, 0.0)
    assert a.object == ObjRef(0x1018, 1)
    assert lc.on_identity_result(0.0, 0x195, token=a.token) == []
    a = _read(lc, 0.0)
    assert a.object == ObjRef(0x1018, 2)
    assert lc.on_identity_result(0.0, 0x401, token=a.token) == []
    assert isinstance(lc.next_action(0.0), WriteStep)


def test_another_device_is_not_configured_and_says_what_it_is() -> None:
    lc = NodeLifecycle([ConfigStep(ObjRef(0x1017, 0), 100, "uint16")], expected_identity=IDENTITY)
    lc.on_bootup(0.0)
    a = _read(lc, 0.0)
    lc.on_identity_result(0.0, 0x195, token=a.token)
    a = _read(lc, 0.0)
    changes = lc.on_identity_result(0.0, 0x999, token=a.token)
    assert changes == [StateChanged(C, W, "wrong device (1018h)"), WrongDevice(0x195, 0x195, 60.0)]
    assert lc.state is W and lc.next_action(1.0) is None
    assert lc.last_error == "wrong device: vendor 0x195 product 0x999, expected vendor 0x195 product 0x401 (1018h against the EDS): not configured"  # fmt: skip


def test_an_identity_read_without_answer_is_retried_and_a_refusal_is_a_wrong_device() -> None:
    lc = NodeLifecycle([], expected_identity=IDENTITY, backoff=Backoff(initial_s=0.5))
    lc.on_bootup(0.0)
    a = _read(lc, 0.0)
    (failed,) = lc.on_identity_result(0.0, None, token=a.token)
    assert isinstance(failed, StepFailed) and failed.retry_in_s == 0.5
    assert lc.next_action(0.25) == Wait("wait", 0.25)
    a = _read(lc, 0.5)
    assert a.object == ObjRef(0x1018, 1)
    lc.on_identity_result(0.5, 0x195, token=a.token)
    a = _read(lc, 0.5)
    # a refusal other than "does not exist": read access denied (CiA 301 table 22)
    lc.on_identity_result(0.5, None, abort_code=0x06010001, token=a.token)
    assert lc.state is W and "product (unreadable)" in (lc.last_error or "")


def _boot_and_read(lc: NodeLifecycle, now: float, answers: list[tuple[int | None, int | None]]) -> list[Any]:  # fmt: skip
    """Boot-up, then each identity read answered with (value, abort code) in turn."""
    changes: list[Any] = list(lc.on_bootup(now))
    for value, code in answers:
        a = _read(lc, now)
        changes += lc.on_identity_result(now, value, code, token=a.token)
    return changes


def test_an_identity_object_the_device_does_not_have_is_not_compared_and_said_once() -> None:
    # CiA 301 7.5.2.20: only 1018h:01 is mandatory; "sub-index does not exist" is no product
    lc = NodeLifecycle([ConfigStep(ObjRef(0x1017, 0), 100, "uint16")], expected_identity=IDENTITY)
    changes = _boot_and_read(lc, 0.0, [(0x195, None), (None, 0x06090011)])
    assert [c for c in changes if not isinstance(c, StateChanged)] == [
        IdentityNotCompared(ObjRef(0x1018, 2), 0x06090011)
    ]
    assert isinstance(lc.next_action(0.0), WriteStep) and lc.state is C
    # the next boot: the same answer (or "object does not exist") is not reported again
    changes = _boot_and_read(lc, 5.0, [(0x195, None), (None, 0x06020000)])
    assert [c for c in changes if not isinstance(c, StateChanged)] == []
    assert isinstance(lc.next_action(5.0), WriteStep)


def test_a_wrong_vendor_is_refused_naming_only_the_numbers_compared() -> None:
    lc = NodeLifecycle([], expected_identity=IDENTITY)
    changes = _boot_and_read(lc, 0.0, [(0x999, None), (None, 0x06090011)])
    assert changes[-1] == WrongDevice(0x195, 0x999, 60.0)
    assert lc.state is W
    assert lc.last_error == "wrong device: vendor 0x999, expected vendor 0x195 (1018h against the EDS): not configured"  # fmt: skip


class TestRefusedDeviceRecheck:
    """A refused device is checked again at its next boot-up, or found running once the
    recheck delay (minutes, growing) has passed; never at each of its heartbeats."""

    def test_found_again_is_ignored_until_the_recheck_and_the_delay_grows(self) -> None:
        lc = NodeLifecycle([], expected_identity=IDENTITY)
        (*_, refused) = _boot_and_read(lc, 0.0, [(0x999, None), (0x401, None)])
        assert refused == WrongDevice(0x195, 0x999, 60.0)
        assert lc.recheck_at_s == 60.0
        assert not lc.may_probe(59.9)
        assert lc.on_found(59.9) == [] and lc.state is W  # a probe answered early: ignored
        assert lc.may_probe(60.0)
        assert states(lc.on_found(60.0)) == [(W, B)]
        lc.on_nmt_sent(60.0)
        changes: list[Any] = []
        for value in (0x999, 0x401):
            a = _read(lc, 60.0)
            changes += lc.on_identity_result(60.0, value, token=a.token)
        assert changes[-1] == WrongDevice(0x195, 0x999, 120.0)  # 2nd refusal in a row
        assert lc.recheck_at_s == 180.0
        delays = [RECHECK_BACKOFF.delay_s(n) for n in range(1, 8)]
        assert delays == [60.0, 120.0, 240.0, 480.0, 960.0, 960.0, 960.0]

    def test_a_boot_up_is_checked_at_once_and_a_configuration_ends_the_refusals(self) -> None:
        lc = NodeLifecycle([], expected_identity=IDENTITY)
        _boot_and_read(lc, 0.0, [(0x999, None), (0x401, None)])
        assert lc.recheck_at_s == 60.0 and lc.refusals == 1
        # the right device is plugged in: its boot-up is checked at once
        changes = _boot_and_read(lc, 10.0, [(0x195, None), (0x401, None)])
        assert lc.recheck_at_s is None and lc.may_probe(10.0)
        assert not [c for c in changes if isinstance(c, WrongDevice)]
        assert lc.next_action(10.0) == SendNmt("nmt_start", 0x01)
        lc.on_nmt_sent(10.0)
        assert lc.state is O and lc.refusals == 0

    def test_a_wrong_device_type_found_by_a_probe_waits_its_recheck_too(self) -> None:
        lc = NodeLifecycle(STEPS, expected_device_type=0x000A0196)
        lc.start(0.0)
        assert lc.on_found(0.5, device_type=0x00020196)[0].recheck_in_s == 60.0
        assert not lc.may_probe(60.0) and lc.may_probe(60.5)
        assert lc.on_found(1.5, device_type=0x00020196) == []  # not reported again
        assert lc.on_found(60.5, device_type=0x00020196) == [
            WrongDevice(0x000A0196, 0x00020196, 120.0)
        ]


class TestTransitionTable:
    """The state changes are the table ``TRANSITIONS`` (h11 ``_state.py`` style): the code
    reads it; our own misuse raises, a peer's event that means nothing is counted."""

    def test_every_state_change_of_a_boot_and_a_loss_is_a_row_of_the_table(self) -> None:
        from canopen_gateway.bus.node.lifecycle import TRANSITIONS

        lc = NodeLifecycle([ConfigStep(ObjRef(0x1017, 0), 100, "uint16")])
        changes = [*lc.on_bootup(0.0)]
        action = lc.next_action(0.0)
        assert isinstance(action, WriteStep)
        changes += lc.on_step_result(0.0, True, token=action.token)
        assert isinstance(lc.next_action(0.0), SendNmt)
        changes += lc.on_nmt_sent(0.0)
        changes += lc.on_lost(1.0)
        moves = [(c.old, c.new) for c in changes if isinstance(c, StateChanged)]
        assert moves == [(W, B), (B, C), (C, LifecycleState.OPERATIONAL), (LifecycleState.OPERATIONAL, W)]
        table = {(old, new) for (old, _event), new in TRANSITIONS.items()}
        assert set(moves) <= table

    def test_a_change_the_table_does_not_define_raises_for_our_own_misuse(self) -> None:
        from canopen_gateway.bus.node.lifecycle import LifecycleError, LifecycleEvent

        lc = NodeLifecycle([])
        with pytest.raises(LifecycleError, match="no transition from waiting on NMT start sent"):
            lc._fire(LifecycleEvent.START_SENT, "a driver bug")
        assert lc.state is W

    def test_events_that_mean_nothing_in_the_state_are_counted_not_acted_on(self) -> None:
        lc = NodeLifecycle([ConfigStep(ObjRef(0x1017, 0), 100, "uint16")])
        assert lc.on_lost(0.0) == []  # never seen: nothing to lose
        lc.on_bootup(0.0)
        action = lc.next_action(0.0)
        assert isinstance(action, WriteStep)
        assert lc.on_step_result(0.0, True, token=action.token + 1) == []  # an old answer
        assert lc.on_found(0.0) == []  # it is configuring already
        assert lc.ignored == {(W, "lost"): 1, (C, "step result"): 1, (C, "found"): 1}
        assert lc.state is C and lc.step_index == 0
