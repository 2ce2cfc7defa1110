"""SimNode core (DS-301) driven with raw frames and a fake clock: boot, NMT, heartbeat,
guarding, SDO, PDOs, EMCY, store/restore. Device: the SGH10 profile (manual 000/003)."""

from __future__ import annotations

import can
import pytest

from canopen_gateway.profiles import load_profile
from canopen_gateway.sim.node import NmtState, SimNode
from canopen_gateway.sim.objects import PersistentStore
from tests.helpers import frame

NODE = 1


def frames(msgs: list[can.Message]) -> list[tuple[int, str]]:
    return [(m.arbitration_id, m.data.hex(" ").upper()) for m in msgs]


def sdo(node: SimNode, hexdata: str, now: float = 0.5) -> list[tuple[int, str]]:
    return frames(node.handle(frame(0x600 + node.node_id, hexdata), now))


def nmt(node: SimNode, cs: int, target: int = NODE, now: float = 0.5) -> list[tuple[int, str]]:
    return frames(node.handle(frame(0x000, f"{cs:02X} {target:02X}"), now))


@pytest.fixture
def node() -> SimNode:
    n = SimNode(load_profile("sgh10"), NODE, motion={"kind": "ramp", "min": 0, "max": 10000})
    n.power_on(0.0)
    return n


def test_power_on_sends_boot_up_and_enters_pre_operational() -> None:
    n = SimNode(load_profile("sgh10"), 5)
    assert frames(n.tick(0.0)) == [(0x705, "00")]
    assert n.nmt_state == NmtState.PRE_OPERATIONAL


def test_nmt_start_stop_pre_operational_for_own_id_and_broadcast(node: SimNode) -> None:
    nmt(node, 0x01)
    assert node.nmt_state == NmtState.OPERATIONAL
    nmt(node, 0x02, target=0)
    assert node.nmt_state == NmtState.STOPPED
    nmt(node, 0x80)
    assert node.nmt_state == NmtState.PRE_OPERATIONAL
    nmt(node, 0x01, target=7)  # another node
    assert node.nmt_state == NmtState.PRE_OPERATIONAL


def test_nmt_reset_node_and_reset_communication_boot_again(node: SimNode) -> None:
    nmt(node, 0x01)
    assert nmt(node, 0x81) == [(0x701, "00")]
    assert node.nmt_state == NmtState.PRE_OPERATIONAL
    nmt(node, 0x01)
    assert nmt(node, 0x82, target=0) == [(0x701, "00")]
    assert node.last_reset == "communication"


def test_stopped_node_answers_no_sdo(node: SimNode) -> None:
    nmt(node, 0x02)
    assert sdo(node, "40 00 10 00 00 00 00 00") == []


def test_heartbeat_is_sent_exactly_at_each_period_boundary(node: SimNode) -> None:
    sdo(node, "2B 17 10 00 64 00 00 00", now=1.0)  # 1017h = 100 ms from t = 1.0
    assert frames(node.tick(1.0999)) == []
    assert frames(node.tick(1.1)) == [(0x701, "7F")]
    assert frames(node.tick(1.1999)) == []
    assert frames(node.tick(1.2)) == [(0x701, "7F")]
    nmt(node, 0x02, now=1.25)
    assert frames(node.tick(1.3)) == [(0x701, "04")]  # heartbeat also in STOPPED


def test_heartbeat_zero_disables_the_producer(node: SimNode) -> None:
    sdo(node, "2B 17 10 00 00 00 00 00")
    assert frames(node.tick(100.0)) == []


def test_node_guarding_toggle_starts_at_zero_and_alternates(node: SimNode) -> None:
    rtr = frame(0x701, rtr=True, dlc=1)
    assert frames(node.handle(rtr, 1.0)) == [(0x701, "7F")]
    assert frames(node.handle(rtr, 1.1)) == [(0x701, "FF")]
    nmt(node, 0x01, now=1.15)
    assert frames(node.handle(rtr, 1.2)) == [(0x701, "05")]
    nmt(node, 0x02, now=1.25)
    assert frames(node.handle(rtr, 1.3)) == [(0x701, "84")]
    nmt(node, 0x82, now=1.35)  # reset communication: toggle starts at 0 again
    assert frames(node.handle(rtr, 1.4)) == [(0x701, "7F")]


def test_tpdo1_follows_the_event_timer_with_a_moving_position(node: SimNode) -> None:
    sdo(node, "2B 00 18 05 64 00 00 00", now=0.0)  # 1800h:05 = 100 ms
    assert frames(node.tick(0.05)) == []  # PRE-OPERATIONAL: no PDO
    nmt(node, 0x01, now=0.1)
    first = node.tick(0.1)
    second = node.tick(0.2)
    assert [m.arbitration_id for m in first + second] == [0x181, 0x181]
    p1 = int.from_bytes(first[0].data[0:4], "little", signed=True)
    p2 = int.from_bytes(second[0].data[0:4], "little", signed=True)
    assert p2 > p1
    assert len(first[0].data) == 6  # position i32 + velocity i16 (manual Table 5)


def test_6200h_and_1800h_05_are_one_value(node: SimNode) -> None:
    sdo(node, "2B 00 62 00 94 11 00 00")
    assert sdo(node, "40 00 18 05 00 00 00 00") == [(0x581, "4B 00 18 05 94 11 00 00")]
    sdo(node, "2B 00 18 05 0A 00 00 00")
    assert sdo(node, "40 00 62 00 00 00 00 00") == [(0x581, "4B 00 62 00 0A 00 00 00")]


def test_tpdo2_on_every_nth_sync_only_when_operational(node: SimNode) -> None:
    sync = frame(0x080)
    assert frames(node.handle(sync, 0.1)) == []
    nmt(node, 0x01, now=0.2)
    assert [m.arbitration_id for m in node.handle(sync, 0.3)] == [0x281]
    sdo(node, "2F 01 18 02 03 00 00 00", now=0.35)  # every 3rd SYNC
    got = [len(node.handle(sync, 0.4 + i / 10)) for i in range(6)]
    assert got == [0, 0, 1, 0, 0, 1]


def test_rtr_on_a_tpdo_cob_id_is_answered_in_operational(node: SimNode) -> None:
    rtr = frame(0x181, rtr=True, dlc=6)
    assert node.handle(rtr, 0.1) == []
    nmt(node, 0x01, now=0.2)
    out = node.handle(rtr, 0.3)
    assert [(m.arbitration_id, len(m.data)) for m in out] == [(0x181, 6)]


def test_cob_id_of_a_valid_pdo_changes_only_after_bit_31(node: SimNode) -> None:
    # 1800h:01 = 0x182 while valid -> 0x08000022
    assert sdo(node, "23 00 18 01 82 01 00 00") == [(0x581, "80 00 18 01 22 00 00 08")]
    assert sdo(node, "23 00 18 01 81 01 00 80") == [(0x581, "60 00 18 01 00 00 00 00")]
    assert sdo(node, "23 00 18 01 82 01 00 00") == [(0x581, "60 00 18 01 00 00 00 00")]
    nmt(node, 0x01)
    sdo(node, "2B 00 18 05 0A 00 00 00", now=1.0)  # timer started: first TPDO after 10 ms
    assert {m.arbitration_id for m in node.tick(1.01)} == {0x182}


def test_sdo_abort_codes(node: SimNode) -> None:
    assert sdo(node, "40 00 70 00 00 00 00 00") == [(0x581, "80 00 70 00 00 00 02 06")]
    assert sdo(node, "40 00 18 04 00 00 00 00") == [(0x581, "80 00 18 04 11 00 09 06")]
    assert sdo(node, "23 00 10 00 00 00 00 00") == [(0x581, "80 00 10 00 02 00 01 06")]
    assert sdo(node, "2F 17 10 00 05 00 00 00") == [(0x581, "80 17 10 00 10 00 07 06")]
    assert sdo(node, "2F 0A 5F 01 80 00 00 00") == [(0x581, "80 0A 5F 01 30 00 09 06")]
    assert sdo(node, "A0 00 10 00 00 00 00 00") == [(0x581, "80 00 10 00 01 00 04 05")]


def test_segmented_download_of_a_long_value_and_toggle_error(node: SimNode) -> None:
    # 6401h:01 (4 bytes) sent segmented: initiate with size, one segment of 4 bytes
    assert sdo(node, "21 01 64 01 04 00 00 00") == [(0x581, "60 01 64 01 00 00 00 00")]
    assert sdo(node, "07 10 00 00 00 00 00 00") == [(0x581, "20 00 00 00 00 00 00 00")]
    assert node.get(0x6401, 1) == 16
    assert sdo(node, "21 01 64 01 04 00 00 00") == [(0x581, "60 01 64 01 00 00 00 00")]
    assert sdo(node, "17 10 00 00 00 00 00 00") == [(0x581, "80 01 64 01 00 00 03 05")]


def test_emcy_history_and_error_register(node: SimNode) -> None:
    out = []
    node.raise_emcy(0xFF05, 0x80, now=1.0)
    out += node.drain()
    assert frames(out) == [(0x081, "05 FF 81 00 00 00 00 00")]
    assert node.get(0x1001, 0) == 0x81
    node.raise_emcy(0xFF05, 0x80, now=1.1)  # once per error event
    assert node.drain() == []
    node.raise_emcy(0xFF15, 0x00, now=1.2)
    assert frames(node.drain()) == [(0x081, "15 FF 81 00 00 00 00 00")]
    assert sdo(node, "40 03 10 00 00 00 00 00") == [(0x581, "4F 03 10 00 02 00 00 00")]
    assert sdo(node, "40 03 10 01 00 00 00 00") == [(0x581, "43 03 10 01 15 FF 00 00")]
    assert sdo(node, "40 03 10 02 00 00 00 00") == [(0x581, "43 03 10 02 05 FF 00 00")]
    node.clear_emcy(0xFF05, now=1.3)
    assert frames(node.drain()) == [(0x081, "00 00 01 00 00 00 00 00")]
    assert sdo(node, "2F 03 10 00 00 00 00 00") == [(0x581, "60 03 10 00 00 00 00 00")]
    assert sdo(node, "40 03 10 00 00 00 00 00") == [(0x581, "4F 03 10 00 00 00 00 00")]


def test_emcy_is_not_sent_in_stopped(node: SimNode) -> None:
    nmt(node, 0x02)
    node.raise_emcy(0xFF05, 0x80, now=1.0)
    assert node.drain() == []
    assert node.get(0x1001, 0) == 0x81


def test_save_survives_power_cycle_and_load_restores_after_reset() -> None:
    store = PersistentStore()
    n = SimNode(load_profile("sgh10"), NODE, store=store)
    n.power_on(0.0)
    sdo(n, "2B 17 10 00 F4 01 00 00")  # 1017h = 500
    n.power_cycle(1.0)
    assert n.get(0x1017, 0) == 0
    sdo(n, "2B 17 10 00 F4 01 00 00", now=1.1)
    assert sdo(n, "23 10 10 01 73 61 76 65", now=1.2) == [(0x581, "60 10 10 01 00 00 00 00")]
    assert frames(n.power_cycle(2.0)) == [(0x701, "00")]
    assert n.get(0x1017, 0) == 500
    assert sdo(n, "23 11 10 01 6C 6F 61 64", now=2.1) == [(0x581, "60 11 10 01 00 00 00 00")]
    assert n.get(0x1017, 0) == 500  # effective after reset
    nmt(n, 0x81, now=2.2)
    assert n.get(0x1017, 0) == 0


def test_wrong_store_signature_aborts_08000020(node: SimNode) -> None:
    assert sdo(node, "23 10 10 01 73 74 6F 72") == [(0x581, "80 10 10 01 20 00 00 08")]
    assert sdo(node, "23 11 10 01 00 00 00 00") == [(0x581, "80 11 10 01 20 00 00 08")]


def test_silenced_node_sends_and_answers_nothing(node: SimNode) -> None:
    sdo(node, "2B 17 10 00 64 00 00 00", now=0.0)
    node.silence()
    assert frames(node.tick(0.1)) == []
    assert sdo(node, "40 00 10 00 00 00 00 00") == []
    node.unsilence(0.5)
    assert frames(node.tick(0.6)) == [(0x701, "7F")]


def test_guarding_rtr_is_not_answered_while_the_heartbeat_producer_runs(node: SimNode) -> None:
    sdo(node, "2B 17 10 00 64 00 00 00", now=1.0)
    assert node.handle(frame(0x701, rtr=True, dlc=1), 1.01) == []


def test_life_guarding_event_after_guard_time_times_factor_without_rtr(node: SimNode) -> None:
    sdo(node, "2B 0C 10 00 64 00 00 00", now=1.0)  # guard time 100 ms
    sdo(node, "2F 0D 10 00 03 00 00 00", now=1.0)  # life time factor 3
    node.tick(2.0)
    assert not node.life_guarding_lost  # not active before the first RTR
    node.handle(frame(0x701, rtr=True, dlc=1), 2.0)
    node.tick(2.3)
    assert not node.life_guarding_lost  # exactly the life time
    node.tick(2.3001)
    assert node.life_guarding_lost
    node.handle(frame(0x701, rtr=True, dlc=1), 2.4)
    assert not node.life_guarding_lost


def test_life_guarding_sends_8130h_where_the_profile_lists_it() -> None:
    n = SimNode(load_profile("posi_plus"), 1)
    n.power_on(0.0)
    sdo(n, "2B 0C 10 00 0A 00 00 00", now=0.1)
    sdo(n, "2F 0D 10 00 02 00 00 00", now=0.1)
    n.handle(frame(0x701, rtr=True, dlc=1), 0.2)
    assert frames(n.tick(0.3)) == [(0x081, "30 81 11 00 00 00 00 00")]
    assert frames(n.handle(frame(0x701, rtr=True, dlc=1), 0.4)) == [
        (0x701, "FF"),
        (0x081, "00 00 00 00 00 00 00 00"),
    ]


def test_read_of_a_write_only_object_aborts_06010001() -> None:
    n = SimNode(load_profile("posi_sf"), 1)
    n.power_on(0.0)
    assert sdo(n, "40 00 23 00 00 00 00 00") == [(0x581, "80 00 23 00 01 00 01 06")]


def test_unfinished_segmented_transfer_is_aborted_after_the_sdo_timeout(node: SimNode) -> None:
    assert sdo(node, "40 08 10 00 00 00 00 00", now=1.0) == [(0x581, "41 08 10 00 05 00 00 00")]
    assert node.tick(1.9) == []
    assert frames(node.tick(2.01)) == [(0x581, "80 08 10 00 00 00 04 05")]


def test_segment_request_without_a_transfer_aborts_05040001(node: SimNode) -> None:
    assert sdo(node, "60 00 00 00 00 00 00 00") == [(0x581, "80 00 00 00 01 00 04 05")]


def test_transmission_type_0_sends_on_sync_only_when_the_data_changed() -> None:
    n = SimNode(load_profile("sgh10"), NODE, motion={"kind": "hold", "hold": 100})
    n.power_on(0.0)
    assert sdo(n, "2F 01 18 02 00 00 00 00") == [(0x581, "60 01 18 02 00 00 00 00")]
    nmt(n, 0x01)
    sync = frame(0x080)
    assert len(n.handle(sync, 1.0)) == 1
    assert n.handle(sync, 1.1) == []
    n.motion.freeze(150)
    assert len(n.handle(sync, 1.2)) == 1


def test_reset_communication_keeps_application_values_reset_node_does_not(node: SimNode) -> None:
    sdo(node, "23 01 64 01 0A 00 00 00")  # 6401h:01 = 10 (application)
    sdo(node, "2B 17 10 00 64 00 00 00")  # 1017h = 100 (communication)
    nmt(node, 0x82)
    assert node.get(0x6401, 1) == 10 and node.get(0x1017, 0) == 0
    sdo(node, "2B 17 10 00 64 00 00 00")
    nmt(node, 0x81)
    assert node.get(0x6401, 1) == 0 and node.get(0x1017, 0) == 0


def test_emcy_cob_id_bit_31_disables_emcy(node: SimNode) -> None:
    sdo(node, "23 14 10 00 81 00 00 80")
    node.raise_emcy(0xFF05, 0x80, now=1.0)
    assert node.drain() == []
    assert node.get(0x1001, 0) == 0x81


def test_a_node_silenced_before_power_on_boots_without_a_word() -> None:
    n = SimNode(load_profile("sgh10"), NODE)
    n.silence()
    assert n.tick(0.0) == []
    assert n.nmt_state == NmtState.PRE_OPERATIONAL
    n.unsilence(1.0)
    assert sdo(n, "40 00 10 00 00 00 00 00", now=1.1) == [(0x581, "43 00 10 00 96 01 0A 00")]


def test_every_profile_feature_has_a_sim_feature() -> None:
    from canopen_gateway.profiles.schema import KNOWN_FEATURES
    from canopen_gateway.sim.features import registered

    assert set(registered()) == KNOWN_FEATURES


@pytest.mark.parametrize("family", ["sgh10", "ap05", "msk5000", "posi_plus", "posi_sf"])
def test_every_builtin_profile_boots_and_answers_1000h(family: str) -> None:
    lp = load_profile(family)
    n = SimNode(lp, 9)
    assert frames(n.power_on(0.0)) == [(0x709, "00")]
    (reply,) = n.handle(frame(0x609, "40 00 10 00 00 00 00 00"), 0.1)
    assert reply.arbitration_id == 0x589 and reply.data[0] == 0x43
    if lp.profile.device_type is not None:
        assert int.from_bytes(reply.data[4:8], "little") == lp.profile.device_type


def test_a_stopped_error_control_sends_no_heartbeat_and_answers_no_guarding(node: SimNode) -> None:
    sdo(node, "2B 17 10 00 64 00 00 00", now=1.0)  # heartbeat 100 ms
    nmt(node, 0x01, now=1.0)
    sdo(node, "2B 00 18 05 32 00 00 00", now=1.0)  # TPDO1 every 50 ms
    node.stop_error_control()
    sent = frames(node.tick(1.1)) + frames(node.tick(1.15))
    assert (0x701, "05") not in sent and any(cob == 0x181 for cob, _ in sent)  # PDOs go on
    node.resume_error_control(1.2)
    assert (0x701, "05") in frames(node.tick(1.2))  # the next heartbeat at once
    sdo(node, "2B 17 10 00 00 00 00 00", now=1.3)  # heartbeat off: node guarding instead
    rtr = frame(0x701, rtr=True, dlc=1)
    node.stop_error_control()
    assert frames(node.handle(rtr, 1.4)) == []
    node.resume_error_control(1.5)
    assert frames(node.handle(rtr, 1.5)) == [(0x701, "05")]
    node.stop_error_control()
    node.power_cycle(2.0)  # a restart brings the heartbeat back
    assert not node.error_control.off
