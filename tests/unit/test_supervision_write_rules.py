"""The rule that keeps a client from defeating supervision (commands.validation), pure: which
writes of 1017h, 100Ch/100Dh and 1016h are refused for which kind of supervision, and that the
value the gateway configured may always be written again."""

from __future__ import annotations

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.commands.validation import is_supervision_object, supervision_problem
from canopen_gateway.device.boot_steps import ConfigStep
from canopen_gateway.device.settings import NodeSettings

HB, GT, LTF = ObjRef(0x1017, 0), ObjRef(0x100C, 0), ObjRef(0x100D, 0)
CONSUMER1 = ObjRef(0x1016, 1)
MASTER = 127


def settings(kind: str) -> NodeSettings:
    return NodeSettings(
        supervision=kind, heartbeat_ms=100, guard_time_ms=200, life_time_factor=3,
        heartbeat_multiple=3.0, boot_timeout_s=10.0, probe_period_s=1.0, sdo_timeout_s=0.5,
        sdo_retries=1, guarding_bit=None, external_heartbeat_ms=0,
        external_heartbeat_source="rpdo", keepalive_ms=0, refresh_on_start=False, rtr_poll_ms=None,
    )  # fmt: skip


def problem(
    kind: str, obj: ObjRef, value: int, steps: list[ConfigStep] | None = None
) -> str | None:
    return supervision_problem("n", settings(kind), steps or [], MASTER, obj, value)


def test_heartbeat_node_refuses_any_other_producer_time_and_accepts_its_own() -> None:
    assert problem("heartbeat", HB, 0) is not None
    assert "1017h = 100 ms" in (problem("heartbeat", HB, 50) or "")
    assert problem("heartbeat", HB, 100) is None
    # guarding objects do not matter while the heartbeat takes precedence
    assert problem("heartbeat", GT, 0) is None and problem("heartbeat", LTF, 0) is None


def test_an_explicit_boot_write_is_the_value_kept() -> None:
    steps = [ConfigStep(HB, 250, "uint16")]
    assert problem("heartbeat", HB, 250, steps) is None
    assert problem("heartbeat", HB, 100, steps) is not None


def test_guarded_node_refuses_guard_changes_and_any_heartbeat() -> None:
    assert problem("guarding", GT, 0) is not None
    assert problem("guarding", LTF, 0) is not None
    assert problem("guarding", GT, 200) is None and problem("guarding", LTF, 3) is None
    assert "takes precedence" in (problem("guarding", HB, 100) or "")
    assert problem("guarding", HB, 0) is None


def test_unsupervised_node_may_change_error_control() -> None:
    for obj, value in ((HB, 0), (HB, 20), (GT, 0), (LTF, 0)):
        assert problem("none", obj, value) is None


def test_consumer_of_the_masters_heartbeat_set_at_boot_is_kept() -> None:
    watching_master = (MASTER << 16) | 1500
    steps = [ConfigStep(CONSUMER1, watching_master, "uint32")]
    assert problem("heartbeat", CONSUMER1, 0, steps) is not None
    assert problem("none", CONSUMER1, 0, steps) is not None
    assert problem("heartbeat", CONSUMER1, watching_master, steps) is None
    # an entry watching another node, or one the boot configuration does not set: free
    other = [ConfigStep(CONSUMER1, (9 << 16) | 1500, "uint32")]
    assert problem("heartbeat", CONSUMER1, 0, other) is None
    assert problem("heartbeat", CONSUMER1, 0) is None


def test_supervision_objects() -> None:
    assert all(is_supervision_object(o) for o in (HB, GT, LTF, CONSUMER1, ObjRef(0x1016, 127)))
    assert not is_supervision_object(ObjRef(0x1016, 0))
    assert not is_supervision_object(ObjRef(0x1800, 5))
