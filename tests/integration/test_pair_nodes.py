"""The nodes under a hot-standby pair, in process on one virtual bus with simulated devices: what
the standby follows of each node (the operator's NMT state, node guarding, the guarding-bit
link) and what the new active gateway makes of it at a take-over (docs/redundancy.md, "What the
standby does" and "At a take-over").

What each gateway sends is recorded at its own driver (``Sent``); A "dies" by sending nothing
more (``Sent.silent``) and doing nothing of its own (``mastering`` False).
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.app import Gateway
from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.northbound.summary import summarize
from tests.helpers import wait_until
from tests.integration.test_pair import LOGICAL, Sent, pair_configs, pair_running

#: fields both members must report alike for a node both hear operational (the "both serve
#: the same" table of docs/redundancy.md)
SAME = ("nmt_state", "alive", "operational", "usable", "lifecycle", "supervision", "link")


def pair(wire: dict[str, Any] | None = None) -> Any:
    """The in-process pair of ``test_pair`` on these configs, B standing by."""
    return pair_running(pair_configs(wire), standby=True)


def kill(a: Gateway, sent_a: Sent) -> None:
    sent_a.silent = True  # not one more frame
    a.master.mastering = False  # and nothing more of its own


def same_diagnostics(a: Gateway, b: Gateway, name: str) -> dict[str, tuple[Any, Any]]:
    """The fields of ``SAME`` where the two members' summaries of ``name`` differ."""
    sa, sb = summarize(a.image.nodes[name]), summarize(b.image.nodes[name])
    return {f: (getattr(sa, f), getattr(sb, f)) for f in SAME if getattr(sa, f) != getattr(sb, f)}


async def test_the_standby_reports_each_node_as_the_active_one_does() -> None:
    async with pair() as (a, b, _sent_a, _sent_b, _sim):
        # the AP05's guarding-bit link: B follows the bit of the RPDOs A sends, and the echoes
        a.master.write_outputs("display", {None: {"control_word": 0}})
        for name in ("wire", "display"):
            await wait_until(lambda n=name: not same_diagnostics(a, b, n), 5, f"B reports {name} as A")
        display = summarize(b.image.nodes["display"])
        assert display.lifecycle == "operational" and display.link is LinkState.OK
        assert display.operational and display.usable
        assert b.master.standby_dropped == 0  # and it built no frame of its own for the nodes
        # a heartbeat node the standby hears steady costs it no wake-up per repeated heartbeat
        assert b.master.nodes["wire"].steady and b.master.nodes["display"].steady


async def test_a_node_the_operator_stopped_stays_stopped_through_a_takeover() -> None:
    async with pair() as (a, b, sent_a, sent_b, sim):
        await wait_until(lambda: not same_diagnostics(a, b, "display"), 5, "B follows")
        a.master.nmt("display", "stop")  # the operator, through the active gateway
        h = b.image.nodes["display"].health
        await wait_until(lambda: h.nmt_state == NmtState.STOPPED, 5, "B hears it stopped")
        assert h.lifecycle == "operational"  # as A says: managed, in the operator's state
        kill(a, sent_a)
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        n = sent_b.count(0x700 + LOGICAL)
        await wait_until(lambda: sent_b.count(0x700 + LOGICAL) >= n + 5, 5, "B masters the bus")
        assert 0x000 not in sent_b.cob_ids()  # no NMT command: not started, not reset
        assert not [d for c, d in sent_b.frames if c == 0x602]  # no SDO (boot step, probe)
        assert sim.nodes["display"].nmt_state == NmtState.STOPPED
        assert sim.nodes["wire"].nmt_state == NmtState.OPERATIONAL
        assert h.alive and h.nmt_state == NmtState.STOPPED and h.loss_count == 0
        assert b.master.nodes["display"].lifecycle.state == "operational"


async def test_a_guarded_node_is_not_guarded_by_the_standby_and_guarding_goes_on_at_a_takeover() -> None:
    # life time 200 ms x 5 = 1 s: longer than this pair's worst take-over (check: 300 ms +
    # B's slot 1 x 200 + 102 x 2 ms + one heartbeat, 100 ms = 804 ms)
    guarded = {"supervision": "guarding", "guard_time_ms": 200, "life_time_factor": 5}
    async with pair(wire=guarded) as (a, b, sent_a, sent_b, sim):
        guard_b = b.master.nodes["wire"].node.supervision.guard
        assert guard_b is not None
        await wait_until(lambda: guard_b.answers >= 5, 5, "B hears A's guarding answers")
        assert 0x701 not in sent_b.cob_ids() and guard_b.rtr_sent == 0  # not one RTR built
        assert b.master.standby_dropped == 0
        assert guard_b.toggle_errors == 0 and b.image.nodes["wire"].health.alive
        kill(a, sent_a)
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        heard = guard_b.answers
        await wait_until(lambda: sent_b.count(0x701) >= 5, 5, "B guards: 5 RTRs")
        await wait_until(lambda: guard_b.answers >= heard + 4, 5, "the device answers B's RTRs")
        # the toggle the node expected next: every answer B's RTRs got is valid
        assert guard_b.toggle_errors == 0 and guard_b.state_errors == 0
        h = b.image.nodes["wire"].health
        assert h.alive and h.loss_count == 0 and h.nmt_state == NmtState.OPERATIONAL
        assert not sim.nodes["wire"].life_guarding_lost  # the device's life guarding held
        assert 0x000 not in sent_b.cob_ids()
        assert not [d for c, d in sent_b.frames if c == 0x601]


async def test_the_standby_counts_a_guarded_node_lost_when_the_active_ones_rtrs_go_unanswered() -> None:
    guarded = {"supervision": "guarding", "guard_time_ms": 100, "life_time_factor": 3}
    async with pair(wire=guarded) as (a, b, _sent_a, sent_b, sim):
        h_b = b.image.nodes["wire"].health
        guard_b = b.master.nodes["wire"].node.supervision.guard
        assert guard_b is not None
        await wait_until(lambda: guard_b.answers >= 3, 5, "B hears the answers")
        sim.runner.call(lambda now: sim.nodes["wire"].stop_error_control())  # no more answers
        await wait_until(lambda: not h_b.alive, 5, "B counts it lost")
        await wait_until(lambda: not a.image.nodes["wire"].health.alive, 5, "as A does")
        assert h_b.loss_count == 1 and h_b.lifecycle == "waiting"
        assert 0x701 not in sent_b.cob_ids()
