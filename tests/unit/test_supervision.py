"""Supervision state machines driven by a fake clock: every timeout edge, toggle and echo case.

Frames are the byte 0 of 700h + node id as printed in the manuals (SGH10 4.5.2/4.5.3, AP05 5.5.2).
"""

from __future__ import annotations

import math

import pytest

from canopen_gateway.bus.error_control.guarding_bit import GuardingBitCheck, LinkFault, LinkOk
from canopen_gateway.bus.error_control.supervision import (
    BootUpSeen,
    HeartbeatConsumer,
    InvalidStateByte,
    Liveness,
    NmtStateChanged,
    NodeAlive,
    NodeGuardingMaster,
    NodeLost,
    SendGuardRtr,
    Supervisor,
    ToggleError,
    WrongState,
)
from canopen_gateway.canopen.states import LinkState, NmtState

PRE_OP = 0x7F  # SGH10 manual 4.5.3: 127 = PRE-OPERATIONAL
OPERATIONAL = 0x05
STOPPED = 0x04
TOGGLE = 0x80  # bit 7 of a guarding answer


def just_after(t: float) -> float:
    return math.nextafter(t, math.inf)


def kinds(outputs: list[object]) -> list[type]:
    return [type(o) for o in outputs]


# --------------------------------------------------------------------------- heartbeat consumer


class TestHeartbeatConsumer:
    def test_timeout_is_multiple_of_producer_time(self) -> None:
        assert HeartbeatConsumer(100).timeout_s == pytest.approx(0.150)
        assert HeartbeatConsumer(100, multiple=3).timeout_s == pytest.approx(0.300)

    def test_starts_unknown_and_never_times_out_before_first_heartbeat(self) -> None:
        hb = HeartbeatConsumer(100)
        assert hb.state is Liveness.UNKNOWN
        assert hb.poll(1000.0) == []
        assert hb.state is Liveness.UNKNOWN
        assert hb.next_deadline() is None

    def test_first_heartbeat_makes_node_alive_with_its_state(self) -> None:
        hb = HeartbeatConsumer(100)
        out = hb.on_heartbeat(PRE_OP, 10.0)
        assert out == [
            NodeAlive(NmtState.PRE_OPERATIONAL),
            NmtStateChanged(None, NmtState.PRE_OPERATIONAL),
        ]
        assert hb.alive and hb.nmt_state is NmtState.PRE_OPERATIONAL

    def test_still_alive_exactly_at_timeout_and_lost_just_after(self) -> None:
        hb = HeartbeatConsumer(100, multiple=1.5)
        hb.on_heartbeat(OPERATIONAL, 10.0)
        deadline = hb.deadline_s
        assert deadline == 10.0 + hb.timeout_s
        assert hb.poll(deadline) == []
        assert hb.alive
        out = hb.poll(just_after(deadline))
        assert kinds(out) == [NodeLost]
        assert hb.lost and hb.losses == 1

    def test_lost_is_reported_once(self) -> None:
        hb = HeartbeatConsumer(100)
        hb.on_heartbeat(OPERATIONAL, 0.0)
        assert kinds(hb.poll(1.0)) == [NodeLost]
        assert hb.poll(2.0) == []
        assert hb.losses == 1

    def test_each_heartbeat_restarts_the_timeout(self) -> None:
        hb = HeartbeatConsumer(100)
        hb.on_heartbeat(OPERATIONAL, 0.0)
        hb.on_heartbeat(OPERATIONAL, 0.140)
        assert hb.poll(0.280) == []
        assert hb.deadline_s == 0.140 + hb.timeout_s

    def test_heartbeat_after_loss_makes_node_alive_again(self) -> None:
        hb = HeartbeatConsumer(100)
        hb.on_heartbeat(OPERATIONAL, 0.0)
        hb.poll(1.0)
        out = hb.on_heartbeat(OPERATIONAL, 2.0)
        assert out == [NodeAlive(NmtState.OPERATIONAL)]
        assert hb.alive

    def test_state_change_is_reported_with_old_and_new(self) -> None:
        hb = HeartbeatConsumer(100)
        hb.on_heartbeat(PRE_OP, 0.0)
        assert hb.on_heartbeat(PRE_OP, 0.1) == []
        out = hb.on_heartbeat(OPERATIONAL, 0.2)
        assert out == [NmtStateChanged(NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL)]
        out = hb.on_heartbeat(STOPPED, 0.3)
        assert out == [NmtStateChanged(NmtState.OPERATIONAL, NmtState.STOPPED)]

    def test_bootup_pauses_monitoring_until_next_heartbeat(self) -> None:
        hb = HeartbeatConsumer(100)
        hb.on_heartbeat(OPERATIONAL, 0.0)
        out = hb.on_frame(0x00, 0.05)
        assert out == [
            BootUpSeen(),
            NmtStateChanged(NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL),
        ]
        assert hb.state is Liveness.UNKNOWN
        # 1017h may be 0 right after a reset: no loss while the gateway configures the node
        assert hb.poll(60.0) == []
        assert kinds(hb.on_heartbeat(PRE_OP, 61.0)) == [NodeAlive]
        assert hb.bootups == 1

    def test_with_grace_bootup_counts_as_alive_until_first_heartbeat_is_due(self) -> None:
        hb = HeartbeatConsumer(100, bootup_grace_s=5.0)
        out = hb.on_bootup(10.0)
        assert out == [
            BootUpSeen(),
            NodeAlive(NmtState.PRE_OPERATIONAL),
            NmtStateChanged(None, NmtState.PRE_OPERATIONAL),
        ]
        assert hb.deadline_s == 15.0
        assert hb.poll(15.0) == []
        out = hb.poll(just_after(15.0))
        assert kinds(out) == [NodeLost]
        assert "within 5 s of the boot-up" in out[0].reason  # type: ignore[union-attr]

    def test_with_grace_first_heartbeat_switches_to_the_normal_timeout(self) -> None:
        hb = HeartbeatConsumer(100, bootup_grace_s=5.0)
        hb.on_bootup(10.0)
        assert hb.on_heartbeat(PRE_OP, 11.0) == []  # already alive, same state
        assert hb.deadline_s == 11.0 + hb.timeout_s

    def test_state_byte_outside_ds301_is_reported_and_ignored(self) -> None:
        hb = HeartbeatConsumer(100)
        hb.on_heartbeat(OPERATIONAL, 0.0)
        assert hb.on_heartbeat(0x33, 0.1) == [InvalidStateByte(0x33)]
        assert hb.last_heartbeat_s == 0.0
        assert hb.invalid_frames == 1

    def test_disabled_producer_time_is_rejected(self) -> None:
        with pytest.raises(ValueError, match="1017h = 0"):
            HeartbeatConsumer(0)


# --------------------------------------------------------------------------- node guarding


def guarding(gt_ms: int = 100, factor: int = 3, t0: float = 0.0) -> NodeGuardingMaster:
    g = NodeGuardingMaster(gt_ms, factor)
    assert g.poll(t0) == [SendGuardRtr()]
    return g


class TestNodeGuardingMaster:
    def test_first_poll_activates_guarding_with_an_rtr(self) -> None:
        g = NodeGuardingMaster(100, 3)
        assert not g.guarding_started
        assert g.poll(5.0) == [SendGuardRtr()]
        assert g.guarding_started and g.rtr_sent == 1

    def test_rtr_every_guard_time_due_exactly_at_its_time(self) -> None:
        g = guarding(t0=0.0)
        nxt = g.next_rtr_s
        assert nxt == pytest.approx(0.100)
        assert g.poll(math.nextafter(nxt, 0.0)) == []
        g.on_response(PRE_OP, 0.01)
        assert g.poll(nxt) == [SendGuardRtr()]
        assert g.next_rtr_s == pytest.approx(0.200)

    def test_late_poll_sends_one_rtr_and_does_not_burst(self) -> None:
        g = guarding(t0=0.0)
        g.on_response(PRE_OP, 0.01)
        out = g.poll(0.25)  # two guard times missed by a slow caller
        assert out.count(SendGuardRtr()) == 1
        assert g.next_rtr_s == pytest.approx(0.35)

    def test_answers_with_alternating_toggle_starting_at_zero_are_valid(self) -> None:
        g = guarding()
        out = g.on_response(PRE_OP, 0.01)  # toggle 0
        assert out == [
            NmtStateChanged(None, NmtState.PRE_OPERATIONAL),
            NodeAlive(NmtState.PRE_OPERATIONAL),
        ]
        assert g.on_response(TOGGLE | PRE_OP, 0.11) == []  # toggle 1
        assert g.on_response(PRE_OP, 0.21) == []  # toggle 0
        assert g.toggle_errors == 0 and g.alive

    def test_first_answer_with_toggle_one_is_a_toggle_error(self) -> None:
        g = guarding()
        out = g.on_response(TOGGLE | PRE_OP, 0.01)
        assert ToggleError(expected=0, received=1, count=1) in out
        assert g.state is Liveness.UNKNOWN
        assert g.last_answer_valid is False

    def test_repeated_toggle_is_an_error_and_does_not_renew_life_time(self) -> None:
        g = guarding(100, 3, t0=0.0)
        g.on_response(PRE_OP, 0.01)  # valid, toggle 0
        out = g.on_response(PRE_OP, 0.11)  # toggle 0 again
        assert ToggleError(expected=1, received=0, count=1) in out
        assert g.last_valid_s == 0.01
        # the life time still runs from the last valid answer
        assert kinds(g.poll(just_after(0.01 + g.life_time_s))) == [NodeLost, SendGuardRtr]

    def test_after_a_toggle_error_the_next_alternating_answer_is_valid_again(self) -> None:
        g = guarding()
        g.on_response(PRE_OP, 0.01)  # 0 ok
        g.on_response(PRE_OP, 0.11)  # 0 again: error (DS-301: treat as not received)
        out = g.on_response(TOGGLE | PRE_OP, 0.21)  # 1: alternates with the previous answer
        assert out == []
        assert g.last_valid_s == 0.21
        assert g.toggle_errors == 1

    def test_stuck_toggle_counts_an_error_per_answer(self) -> None:
        g = guarding()
        g.on_response(PRE_OP, 0.01)
        for i in range(3):
            g.on_response(PRE_OP, 0.11 + i * 0.1)
        assert g.toggle_errors == 3

    def test_lost_exactly_after_life_time_without_valid_answer(self) -> None:
        g = guarding(100, 3, t0=0.0)
        g.on_response(PRE_OP, 0.05)
        deadline = g.deadline_s
        assert deadline == 0.05 + g.life_time_s
        assert g.life_time_s == pytest.approx(0.300)
        assert NodeLost not in kinds(g.poll(deadline))
        assert not g.lost
        out = g.poll(just_after(deadline))
        assert NodeLost in kinds(out)
        assert g.lost and g.losses == 1
        assert NodeLost not in kinds(g.poll(1.0))

    def test_node_that_never_answers_is_lost_after_life_time_from_activation(self) -> None:
        g = guarding(100, 2, t0=1.0)
        assert NodeLost not in kinds(g.poll(1.0 + g.life_time_s))
        assert NodeLost in kinds(g.poll(just_after(1.0 + g.life_time_s)))

    def test_valid_answer_after_loss_recovers(self) -> None:
        g = guarding(100, 3, t0=0.0)
        g.on_response(PRE_OP, 0.01)
        g.poll(1.0)
        assert g.lost
        out = g.on_response(TOGGLE | PRE_OP, 1.05)
        assert out == [NodeAlive(NmtState.PRE_OPERATIONAL)]
        assert g.alive

    def test_wrong_state_is_reported_counted_and_not_valid(self) -> None:
        g = guarding()
        g.expect(NmtState.OPERATIONAL)
        out = g.on_response(PRE_OP, 0.01)
        assert WrongState(NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL, 1) in out
        assert NmtStateChanged(None, NmtState.PRE_OPERATIONAL) in out
        assert g.state is Liveness.UNKNOWN and g.state_errors == 1
        out = g.on_response(TOGGLE | OPERATIONAL, 0.11)
        assert NodeAlive(NmtState.OPERATIONAL) in out

    def test_persisting_wrong_state_ends_in_lost(self) -> None:
        g = guarding(100, 3, t0=0.0)
        g.on_response(OPERATIONAL, 0.01)
        g.expect(NmtState.OPERATIONAL)
        toggle = TOGGLE
        t = 0.11
        while t < 0.5:
            g.on_response(toggle | STOPPED, t)
            toggle ^= TOGGLE
            t += 0.1
        assert NodeLost in kinds(g.poll(just_after(0.01 + g.life_time_s)))

    def test_bootup_restarts_toggle_at_zero(self) -> None:
        g = guarding()
        g.on_response(PRE_OP, 0.01)
        g.on_response(TOGGLE | PRE_OP, 0.11)
        out = g.on_bootup(0.15)
        assert BootUpSeen() in out
        assert g.state is Liveness.UNKNOWN
        assert g.on_response(PRE_OP, 0.21) == [NodeAlive(NmtState.PRE_OPERATIONAL)]
        assert g.toggle_errors == 0

    def test_disabled_guarding_is_rejected(self) -> None:
        with pytest.raises(ValueError, match="deactivates"):
            NodeGuardingMaster(0, 3)
        with pytest.raises(ValueError, match="deactivates"):
            NodeGuardingMaster(100, 0)


# --------------------------------------------------------------------------- guarding bit

GUARDING_BIT = 1 << 8  # AP05 manual 5.3.2 / 5.3.3: bit 8 of control and status word


def status_bit(status_word: int) -> int:
    return 1 if status_word & GUARDING_BIT else 0


class TestGuardingBitCheck:
    def test_unknown_until_first_echo_and_first_bit_sent_is_one(self) -> None:
        gb = GuardingBitCheck(tolerance_missed=2, tolerance_s=1.0)
        assert gb.state is LinkState.UNKNOWN
        assert gb.on_status(0, 0.0) == []  # nothing sent yet: ignored
        assert gb.next_bit(0.0) == 1
        assert gb.on_status(status_bit(0x0100), 0.01) == [LinkOk()]
        assert gb.state is LinkState.OK

    def test_bit_toggles_only_after_echo(self) -> None:
        gb = GuardingBitCheck()
        assert gb.next_bit(0.0) == 1
        assert gb.next_bit(0.01) == 1  # not echoed yet: repeat
        gb.on_status(1, 0.02)
        assert gb.next_bit(0.03) == 0
        gb.on_status(0, 0.04)
        assert gb.next_bit(0.05) == 1
        assert gb.echoes == 2 and gb.sent == 4

    def test_tolerated_misses_then_fault_on_one_more(self) -> None:
        gb = GuardingBitCheck(tolerance_missed=2, tolerance_s=10.0)
        gb.next_bit(0.0)
        gb.on_status(1, 0.01)
        gb.next_bit(0.02)  # now 0
        assert gb.on_status(1, 0.03) == []
        assert gb.on_status(1, 0.04) == []
        assert gb.state is LinkState.OK
        out = gb.on_status(1, 0.05)
        assert kinds(out) == [LinkFault]
        assert gb.state is LinkState.FAULT and gb.faults == 1
        assert gb.on_status(1, 0.06) == []  # fault reported once

    def test_fault_clears_when_echo_returns(self) -> None:
        gb = GuardingBitCheck(tolerance_missed=0, tolerance_s=10.0)
        gb.next_bit(0.0)
        assert kinds(gb.on_status(0, 0.01)) == [LinkFault]
        assert gb.on_status(1, 0.02) == [LinkOk()]
        assert gb.state is LinkState.OK and gb.consecutive_missed == 0

    def test_no_echo_fault_exactly_after_tolerance_time(self) -> None:
        gb = GuardingBitCheck(tolerance_missed=100, tolerance_s=0.5)
        gb.next_bit(2.0)
        gb.next_bit(2.3)  # a repeat does not restart the clock
        assert gb.poll(2.5) == []
        assert gb.state is LinkState.UNKNOWN
        out = gb.poll(just_after(2.5))
        assert kinds(out) == [LinkFault]
        assert gb.poll(3.0) == []

    def test_echoed_link_without_new_rpdo_has_no_deadline(self) -> None:
        gb = GuardingBitCheck(tolerance_s=0.5)
        gb.next_bit(0.0)
        gb.on_status(1, 0.01)
        assert gb.next_deadline() is None
        assert gb.poll(100.0) == []
        assert gb.state is LinkState.OK

    def test_status_word_losing_the_bit_after_echo_counts_as_missed(self) -> None:
        gb = GuardingBitCheck(tolerance_missed=1, tolerance_s=10.0)
        gb.next_bit(0.0)
        gb.on_status(1, 0.01)
        gb.on_status(0, 0.02)  # e.g. the device reset its status word
        assert kinds(gb.on_status(0, 0.03)) == [LinkFault]
        assert gb.missed == 2

    def test_reset_forgets_expectation(self) -> None:
        gb = GuardingBitCheck()
        gb.next_bit(0.0)
        gb.reset()
        assert gb.state is LinkState.UNKNOWN
        assert gb.on_status(0, 1.0) == []
        assert gb.next_bit(1.0) == 1



# --------------------------------------------------------------------------- the shared base


def _alive_heartbeat() -> tuple[Supervisor, float]:
    hb = HeartbeatConsumer(100, 1.5)
    hb.on_heartbeat(OPERATIONAL, 1.0)
    return hb, 1.0 + 0.15


def _alive_guarding() -> tuple[Supervisor, float]:
    g = NodeGuardingMaster(100, 3)
    g.poll(1.0)  # activates guarding: first RTR
    g.on_response(OPERATIONAL, 1.01)
    return g, 1.01 + 0.3


@pytest.mark.parametrize("make", [_alive_heartbeat, _alive_guarding], ids=["heartbeat", "guarding"])
def test_heartbeat_and_guarding_answer_the_liveness_queries_of_one_base(make) -> None:
    """``alive`` / ``lost`` / ``deadline_s`` and the loss count are the base's (``Supervisor``):
    alive up to the deadline included, lost at the next instant, then no deadline."""
    sup, deadline = make()
    assert isinstance(sup, Supervisor)
    assert sup.alive and not sup.lost and sup.deadline_s == pytest.approx(deadline)
    assert not [o for o in sup.poll(sup.deadline_s) if isinstance(o, NodeLost)]
    lost = [o for o in sup.poll(just_after(sup.deadline_s)) if isinstance(o, NodeLost)]
    assert len(lost) == 1 and sup.lost and not sup.alive and sup.state is Liveness.LOST
    assert sup.losses == 1 and sup.deadline_s is None


@pytest.mark.parametrize("first_toggle", [0, 1])
def test_a_listener_joining_a_guarded_bus_follows_the_toggle_it_hears_first(first_toggle: int) -> None:
    """A pair's standby that joins while the active master guards the node hears an answer of
    either toggle first: it is where that master's guarding is, not a toggle error; from then
    on the toggle must alternate."""
    g = NodeGuardingMaster(100, 3)  # never polled: another master sends the RTRs
    first = [o for o in g.on_response(OPERATIONAL | first_toggle << 7, 1.0) if isinstance(o, ToggleError)]
    assert first == [] and g.alive and g.toggle_errors == 0
    assert [o for o in g.on_response(OPERATIONAL | (first_toggle ^ 1) << 7, 1.1) if isinstance(o, ToggleError)] == []
    repeated = g.on_response(OPERATIONAL | (first_toggle ^ 1) << 7, 1.2)
    assert [o for o in repeated if isinstance(o, ToggleError)] and g.toggle_errors == 1


def test_the_guarding_master_still_wants_toggle_0_first() -> None:
    """The master that activates guarding (its first RTR) expects toggle 0 (DS-301)."""
    g = NodeGuardingMaster(100, 3)
    g.poll(1.0)
    assert [o for o in g.on_response(OPERATIONAL | 0x80, 1.01) if isinstance(o, ToggleError)]
