"""A node another master manages (lifecycle LISTENING, canopen_gateway.bus.node.listening) on a fake
clock: the lifecycle rows of listening, what the standby follows of a node's life (HeardLife),
node guarding while listening and at a take-over, and the guarding bit of heard RPDOs.

``PairHarness`` is test_node's harness (the active gateway's node, the scripted device, a fake
clock) with a second node built listening: it hears every frame the device sends and every
frame the active node sends (NMT commands, guarding RTRs, RPDOs), as a pair's standby on the
same bus does. ``take_over`` makes the listening node the harness's node: the old active one is
gone (it sends nothing more), the new one drives the device from then on.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest

from canopen_gateway.bus.error_control.guarding_bit import GuardingBitCheck
from canopen_gateway.bus.events import Send
from canopen_gateway.bus.node.lifecycle import (
    TRANSITIONS,
    LifecycleEvent,
    LifecycleState,
    NodeLifecycle,
    StateChanged,
)
from canopen_gateway.bus.node.listening import LIFE, SETTLE_S, HeardLife, Life
from canopen_gateway.bus.node.parts import build_node
from canopen_gateway.canopen.cia301 import NMT_COMMANDS
from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.image import NodeImage
from tests.helpers import make_config, resolved
from tests.unit.test_node import Harness

L = LifecycleState.LISTENING
GUARDED = {"supervision": "guarding", "guard_time_ms": 100, "life_time_factor": 5}


class PairHarness(Harness):
    def __init__(self, profile: str = "posi_plus", node_id: int = 3, **node: Any):
        super().__init__(profile, node_id=node_id, **node)
        cfg = make_config(
            [{"name": "n", "node_id": node_id, "profile": profile, **node}],
            master={"boot_timeout_s": 5, "heartbeat_timeout_multiple": 1.5},
        )
        rn = resolved(cfg)[cfg.nodes[0].name]
        self.standby_image = NodeImage("n", node_id, rn.lp.family, [s.name for s in rn.lp.profile.signals])
        self.standby = build_node(rn, self.standby_image, listening=True).node
        self.standby_sent: list[Send] = []  # what the listening node asked to send: nothing
        self.active_image = self.image

    def _standby(self, outs: list[Any]) -> None:
        self.standby_sent += [o for o in outs if isinstance(o, Send)]

    def _take(self, outs: list[Any]) -> None:
        super()._take(outs)
        s = self.standby
        if s is None or s is self.node:
            return
        for o in outs:  # the active node's frames, as the standby hears them on the bus
            if not isinstance(o, Send):
                continue
            if o.cob_id == 0x000:
                command = next(c for c, b in NMT_COMMANDS.items() if b == o.data[0])
                s.on_nmt_command(command)
            elif o.cob_id == 0x700 + s.node_id and o.rtr:
                self._standby(s.on_guard_rtr(self.now))
            elif o.rpdo:
                self._standby(s.on_rpdo_heard(o.cob_id, o.data, 0.0, self.now))

    def _rx(self, cob: int, data: bytes) -> Any:
        to_active = super()._rx(cob, data)
        standby = self.standby

        def deliver() -> list[Any]:
            if standby is not None and standby is not self.node and cob >= 0x700:
                self._standby(standby.on_nmt_ec(data[0], self.now))
            return to_active()

        return deliver

    def bootup(self, at: float) -> None:
        def boot() -> list[Any]:
            self.device.boot()
            standby = self.standby
            if standby is not None and standby is not self.node:
                self._standby(standby.on_nmt_ec(0x00, self.now))
            return self.node.on_nmt_ec(0x00, self.now)

        self.at(at, boot)

    def take_over(self) -> None:
        """The active node is gone; the listening one becomes the harness's node."""
        assert self.standby is not None
        self.node, self.image = self.standby, self.standby_image
        self._take(self.node.take_over(self.now))

    def guard_rtrs(self, after: float) -> list[float]:
        return [t for t, s in self.sent if s.rtr and t > after]


def running(**node: Any) -> PairHarness:
    h = PairHarness(**{**GUARDED, **node})
    h.start()
    h.bootup(0.5)
    h.run_until(3.0)
    assert h.active_image.health.nmt_state == NmtState.OPERATIONAL
    return h


# --------------------------------------------------------------------------- lifecycle rows


@pytest.mark.parametrize("state", ["waiting", "booting", "configuring", "operational"])
def test_every_state_listens_when_another_master_manages_the_node(state: str) -> None:
    lc = NodeLifecycle([])
    lc.state = LifecycleState(state)
    (change,) = lc.on_listen(1.0)
    assert isinstance(change, StateChanged) and change.new is L
    assert lc.next_action(1.0) is None and lc.next_deadline() is None


def test_a_listening_lifecycle_ignores_what_it_hears_and_never_acts() -> None:
    lc = NodeLifecycle([])
    lc.on_listen(0.0)
    assert lc.on_bootup(1.0) == [] and lc.on_found(1.0) == [] and lc.on_lost(1.0) == []
    assert lc.poll(100.0) == [] and lc.next_action(100.0) is None
    assert lc.state is L and lc.ignored[(L, "boot-up")] == 1


def test_a_takeover_adopts_a_listening_node_or_waits_to_configure_it() -> None:
    adopted, taken = NodeLifecycle([]), NodeLifecycle([], boot_timeout_s=2.0)
    adopted.on_listen(0.0)
    taken.on_listen(0.0)
    assert adopted.on_take_over(1.0, adopt=True)[0].new is LifecycleState.OPERATIONAL  # type: ignore[union-attr]
    assert taken.on_take_over(1.0, adopt=False)[0].new is LifecycleState.WAITING  # type: ignore[union-attr]
    assert taken.boot_deadline_s == 3.0  # found and configured as usual from the take-over
    assert adopted.on_take_over(2.0, adopt=True) == []  # not listening: nothing to take over
    # only a listening node is adopted or taken over (the table's rows)
    assert {s for s, e in TRANSITIONS if e in (LifecycleEvent.ADOPTED, LifecycleEvent.TAKEN_OVER)} == {L}


# --------------------------------------------------------------------------- HeardLife


def test_heard_life_follows_the_table_of_the_module_docstring() -> None:
    joined = HeardLife()
    joined.on_state(NmtState.OPERATIONAL, 0.0)  # joined a running bus: heard operational
    assert joined.started and joined.lifecycle(alive=True) == "operational"
    joined.on_nmt_command("preop")  # the operator's state of a started node
    assert joined.life is Life.HELD
    assert joined.adopt_in(True, NmtState.PRE_OPERATIONAL, True) is NmtState.PRE_OPERATIONAL
    joined.on_nmt_command("stop")
    assert joined.adopt_in(True, NmtState.STOPPED, False) is NmtState.STOPPED
    assert joined.adopt_in(False, NmtState.STOPPED, True) is None  # not alive: configured as usual
    assert joined.lifecycle(alive=False) == "waiting"

    rebooted = HeardLife()
    rebooted.on_state(NmtState.OPERATIONAL, 0.0)
    rebooted.on_restart()  # a boot-up: the other master configures it again
    rebooted.on_state(NmtState.OPERATIONAL, 0.1)  # its state alone says nothing yet...
    assert not rebooted.started and rebooted.lifecycle(alive=True) == "unknown"
    rebooted.on_nmt_command("preop")  # ...the configuration's NMT pre-operational neither
    assert rebooted.adopt_in(True, NmtState.PRE_OPERATIONAL, True) is None
    rebooted.on_nmt_command("start")  # the heard start
    assert rebooted.adopt_in(True, NmtState.OPERATIONAL, True) is NmtState.OPERATIONAL
    rebooted.on_nmt_command("reset-comm")
    assert not rebooted.started and rebooted.life is Life.BOOTING


@pytest.mark.parametrize("what", sorted(LIFE))
def test_every_row_of_the_life_table_is_what_each_thing_heard_does(what: str) -> None:
    heard: dict[str, Callable[[HeardLife], None]] = {
        "start": lambda h: h.on_nmt_command("start"),
        "hold": lambda h: h.on_nmt_command("preop"),
        "restart": lambda h: h.on_restart(),
        "operational": lambda h: h.on_state(NmtState.OPERATIONAL, 0.0),
        "fallen": lambda h: h.on_state(NmtState.PRE_OPERATIONAL, 0.0),
        "lost": lambda h: h.on_lost(),
        "sdo": lambda h: h.on_sdo_request(0.0),
    }
    for before, after in LIFE[what].items():
        h = HeardLife()
        h.life = before
        heard[what](h)
        assert h.life is after, (what, before)
    assert set(heard) == set(LIFE) and all(set(row) == set(Life) for row in LIFE.values())


def test_a_loss_is_not_a_restart_a_node_heard_operational_again_is_started() -> None:
    h = HeardLife()
    h.on_state(NmtState.OPERATIONAL, 0.0)
    h.on_lost()  # the node silent: gone, or this gateway deaf (its cable cut)
    assert not h.started and h.life is Life.UNKNOWN
    h.on_state(NmtState.OPERATIONAL, 3.0)  # heard again, no boot-up: running as before
    assert h.started and h.adopt_in(True, NmtState.OPERATIONAL, True) is NmtState.OPERATIONAL


def test_a_node_first_heard_pre_operational_is_kept_so_only_when_a_master_kept_it_so() -> None:
    h = HeardLife()
    h.on_state(NmtState.PRE_OPERATIONAL, 0.0)  # joined (or back): its cause not heard
    assert h.life is Life.QUIET and h.lifecycle(alive=True) == "unknown"
    assert h.adopt_in(True, NmtState.PRE_OPERATIONAL, master_heard=True) is NmtState.PRE_OPERATIONAL
    assert h.adopt_in(True, NmtState.PRE_OPERATIONAL, master_heard=False) is None  # a first start
    h.on_sdo_request(1.0)  # the active master configures it
    assert h.life is Life.BOOTING and h.adopt_in(True, NmtState.PRE_OPERATIONAL, True) is None


def test_a_booting_node_heard_operational_without_sdo_for_the_settle_time_is_started() -> None:
    """Its NMT start was not heard (a frame lost): operational, and nobody configures it."""
    h = HeardLife()
    h.on_restart()
    h.on_state(NmtState.OPERATIONAL, 10.0)
    h.on_sdo_request(10.5)  # still configured: the settle time runs from here
    h.on_state(NmtState.OPERATIONAL, math.nextafter(10.5 + SETTLE_S, 0))
    assert h.life is Life.BOOTING
    h.on_state(NmtState.OPERATIONAL, 10.5 + SETTLE_S)
    assert h.started


# --------------------------------------------------------------------------- the node


def test_a_listening_node_sends_nothing_and_reports_what_the_active_one_reports() -> None:
    h = running()
    assert h.standby_sent == []  # no RTR, no NMT, no SDO built, ever
    sb, act = h.standby_image.health, h.active_image.health
    assert (sb.lifecycle, sb.nmt_state, sb.alive) == (act.lifecycle, act.nmt_state, act.alive)
    assert sb.lifecycle == "operational"  # heard the NMT start after the boot-up
    assert h.standby is not None and h.standby.supervision.guard is not None
    active_guard = h.parts.node.supervision.guard
    assert active_guard is not None  # it followed every answer, as the active one did:
    assert h.standby.supervision.guard.toggle_errors == active_guard.toggle_errors == 0


def test_a_guarded_node_is_not_lost_on_the_standby_while_nobody_guards_it() -> None:
    h = running()
    assert h.standby is not None
    h.node = h.standby  # the active one is gone: nobody guards
    h.run_until(60.0)
    assert h.standby_sent == [] and h.standby_image.health.alive
    assert h.standby_image.health.loss_count == 0


def test_the_standby_loses_a_guarded_node_after_more_unanswered_rtrs_than_the_life_time_factor() -> None:
    h = running()
    h.device.powered = False  # the device stops answering the active one's RTRs
    off = h.now
    h.run_until(off + 5 * 0.1 - 0.01)  # five RTRs: the life time factor
    assert h.standby_image.health.alive
    h.run_until(off + 1.0)
    assert not h.standby_image.health.alive and h.standby_image.health.loss_count == 1
    assert h.standby_image.health.lifecycle == "waiting" and h.standby_sent == []


def test_after_a_takeover_guarding_goes_on_with_the_toggle_the_node_expects_next() -> None:
    h = running()
    t = h.now + 0.25  # within the life time (100 ms x 5)
    h.run_until(t)
    guard = h.standby.supervision.guard if h.standby is not None else None
    assert guard is not None
    errors = (guard.toggle_errors, guard.state_errors)  # the harness's, heard as the active's
    h.take_over()
    h.run_until(t + 3.0)
    assert (guard.toggle_errors, guard.state_errors) == errors  # not one error since
    assert len(h.guard_rtrs(after=t)) >= 25
    hl = h.image.health
    assert hl.alive and hl.loss_count == 0 and hl.nmt_state == NmtState.OPERATIONAL
    assert not [s for tt, s in h.sent if tt >= t and (s.cob_id == 0x000 or s.cob_id == 0x603)]


@pytest.mark.parametrize(("command", "state"), [("preop", NmtState.PRE_OPERATIONAL), ("stop", NmtState.STOPPED)])
def test_a_node_the_operator_commanded_is_adopted_in_that_state(command: str, state: NmtState) -> None:
    h = running()
    h.node.on_nmt_command(command)
    h._take([Send(0x000, bytes([NMT_COMMANDS[command], 3]))])  # the frame the active one sends
    h.run_until(h.now + 1.0)
    assert h.standby_image.health.nmt_state == state
    t = h.now
    guard = h.standby.guard if h.standby is not None else None
    assert guard is not None
    errors = (guard.toggle_errors, guard.state_errors)
    h.take_over()
    h.run_until(t + 3.0)
    assert not [s for tt, s in h.sent if tt >= t and (s.cob_id == 0x000 or s.cob_id == 0x603)]
    hl = h.image.health
    assert h.device.state == state and hl.nmt_state == state and hl.alive
    assert hl.lifecycle == "operational"
    assert (guard.toggle_errors, guard.state_errors) == errors  # it expects the adopted state
    assert len(h.guard_rtrs(after=t)) >= 25


def test_a_node_being_configured_at_a_takeover_is_configured_as_usual() -> None:
    h = running()
    h.device.sdo_delay_s = 1.0  # the old active one's configuration is slow
    h.bootup(h.now + 0.1)
    h.run_until(h.now + 0.5)  # boot-up heard, configuration under way: not heard started
    assert h.standby_image.health.lifecycle == "unknown"
    t = h.now
    h.take_over()
    h.device.sdo_delay_s = 0.001
    h.run_until(t + 5.0)
    assert h.nmt_start_time(after=t) > t  # found, configured and started by the new one
    assert h.image.health.lifecycle == "operational"


# --------------------------------------------------------------------------- guarding bit


def test_the_guarding_bit_of_a_heard_rpdo_is_the_expectation_of_the_link_check() -> None:
    check = GuardingBitCheck(tolerance_missed=3, tolerance_s=1.0)
    check.heard(1, 0.0)
    assert check.on_status(1, 0.01) and check.state is LinkState.OK
    check.heard(1, 0.1)  # the same bit again (the echo not toggled yet): nothing pending
    assert check.deadline_s is None
    check.heard(0, 0.2)
    assert check.deadline_s == 1.2  # toggled: its echo is due within the tolerance
    assert check.next_bit(0.3) == 0  # a take-over goes on from the bit heard (still unechoed)


def test_a_gateway_that_stands_down_keeps_its_nodes_started_and_takes_them_back_as_they_run() -> None:
    h = running()
    node = h.parts.node  # the active one's node
    t = h.now
    h._take(node.stand_by(t))
    assert node.listening and h.active_image.health.lifecycle == "operational"
    h._take(node.stand_by(t))  # standing by again changes nothing of what it knew
    assert node.heard.started
    h.standby = None  # the other listening node plays no part here
    h.run_until(t + 0.3)  # within the life time (100 ms x 5): see test_pair_check
    assert not [s for tt, s in h.sent if tt >= t and not s.rtr]  # listening: nothing sent...
    assert not [s for tt, s in h.sent if tt >= t and s.rtr]  # ...not even a guarding RTR
    h._take(node.take_over(h.now))
    h._take(node.take_over(h.now))  # a second take-over: it is ours already
    t2 = h.now
    h.run_until(t2 + 2.0)
    assert not [s for tt, s in h.sent if tt >= t2 and (s.cob_id == 0x000 or s.cob_id == 0x603)]
    assert node.lifecycle.state is LifecycleState.OPERATIONAL and len(h.guard_rtrs(after=t2)) >= 15


# --------------------------------------------------------------------------- a standby's own outage


def lose_on_the_standby(h: PairHarness) -> None:
    """The standby counts the node lost (more RTRs than the life time factor heard without an
    answer heard): the node gone, or this gateway deaf for a while."""
    assert h.standby is not None
    for _ in range(6):
        h._standby(h.standby.on_guard_rtr(h.now))
    assert not h.standby_image.health.alive


def nmt_and_sdo_after(h: PairHarness, t: float) -> list[Send]:
    return [s for tt, s in h.sent if tt >= t and (s.cob_id == 0x000 or s.cob_id == 0x603)]


def test_a_loss_on_the_standby_is_not_a_restart_the_node_heard_running_again_is_adopted() -> None:
    h = running()
    lose_on_the_standby(h)
    h.run_until(h.now + 1.0)  # heard again (no boot-up): running as it was
    assert h.standby_image.health.alive and h.standby_image.health.lifecycle == "operational"
    t = h.now
    h.take_over()
    h.run_until(t + 3.0)
    assert nmt_and_sdo_after(h, t) == []  # adopted: nothing sent to it
    assert h.image.health.lifecycle == "operational" and h.device.state == NmtState.OPERATIONAL


def test_the_operators_pre_operational_state_is_kept_through_a_loss_on_the_standby() -> None:
    h = running()
    h.node.on_nmt_command("preop")
    h._take([Send(0x000, bytes([NMT_COMMANDS["preop"], 3]))])  # the operator, through the active one
    h.run_until(h.now + 0.5)
    lose_on_the_standby(h)
    h.run_until(h.now + 1.0)  # heard again, pre-operational: its cause not heard since the loss
    t = h.now
    h.take_over()  # an active master was heard keeping it so
    h.run_until(t + 3.0)
    assert nmt_and_sdo_after(h, t) == []
    assert h.device.state == NmtState.PRE_OPERATIONAL and h.image.health.lifecycle == "operational"


def test_a_node_fallen_pre_operational_by_itself_is_started_again_with_nmt_start_only() -> None:
    h = running()
    h.device.state = NmtState.PRE_OPERATIONAL  # a device-side timeout: no command heard
    h.run_until(h.now + 0.25)  # two answers (guarding errors: not the state expected)
    assert h.standby is not None and h.standby.heard.life is Life.FELL
    t = h.now
    h.take_over()
    h.run_until(t + 3.0)
    assert nmt_and_sdo_after(h, t) == [Send(0x000, bytes([0x01, 3]))]  # no SDO: configuration kept
    assert h.device.state == NmtState.OPERATIONAL and h.image.health.nmt_state == NmtState.OPERATIONAL
    assert any("fallen by itself" in n.text for _, n in h.notes)


def test_a_node_that_falls_right_after_its_adoption_is_started_again_later_ones_are_left_alone() -> None:
    h = running()
    t = h.now
    h.take_over()
    h.run_until(t + 0.15)
    h.device.state = NmtState.PRE_OPERATIONAL  # its timeout of the take-over expires now
    h.run_until(t + 0.9)
    assert nmt_and_sdo_after(h, t) == [Send(0x000, bytes([0x01, 3]))]
    assert h.device.state == NmtState.OPERATIONAL
    h.run_until(t + 5.0)
    h.device.state = NmtState.PRE_OPERATIONAL  # long after: as with one gateway, a guarding
    h.run_until(t + 8.0)  # error, the node lost, found by a probe and configured as usual
    later = nmt_and_sdo_after(h, t + 5.0)
    assert later and later[0].cob_id == 0x603 and len(nmt_and_sdo_after(h, t)) == 1 + len(later)


# --------------------------------------------------------------------------- a split of the bus healed


def test_a_pair_members_node_lost_while_running_and_heard_running_again_resumes_without_nmt_or_sdo() -> None:
    """The bus split between the member and the node (the other member mastered it meanwhile),
    then healed: no boot-up was heard, the node reports OPERATIONAL: its configuration is
    intact, it is taken as it runs. Not probed while lost (a probe answered would reconfigure)."""
    h = running()
    h.take_over()  # the member that was standby masters the node (as after any take-over)
    t = h.now
    h.run_until(t + 1.0)
    h.device.powered = False  # the split: the node hears nothing of this member, nor it of it
    h.run_until(t + 3.0)
    assert not h.image.health.alive and h.node.lifecycle.resumable
    h.device.powered = True  # healed
    h.run_until(t + 5.0)
    assert nmt_and_sdo_after(h, t) == []
    assert h.node.lifecycle.state is LifecycleState.OPERATIONAL and h.image.health.alive
    assert h.image.health.loss_count == 1 and h.device.state == NmtState.OPERATIONAL


def test_a_resumable_node_that_booted_meanwhile_is_configured_as_usual() -> None:
    h = running()
    h.take_over()
    t = h.now
    h.device.powered = False
    h.run_until(t + 2.0)
    h.device.powered = True
    h.bootup(t + 2.1)  # it restarted: its configuration is gone
    h.run_until(t + 6.0)
    assert h.nmt_start_time(after=t) > t and [s for _, s in h.sent if s.cob_id == 0x603]
