"""A node that only listens (lifecycle LISTENING: a pair's standby): what it heard of the node's
life under the other master, and what a take-over makes of it.

Rule: the standby sends nothing, so everything it knows of a node it heard. ``HeardLife`` keeps
whether the other master started the node (its NMT start heard, or, when the standby joined a
running bus, the node heard OPERATIONAL before any boot-up or loss) and from that the words the
standby's diagnostics say. At a take-over a node heard started and alive is adopted in the NMT
state it reports (operational, or pre-operational / stopped as the operator's NMT command left
it): nothing is sent to it. Any other node is found and configured as usual.

=============================================  ================================================
heard                                          started
=============================================  ================================================
NMT start (to the node or to all)              yes
OPERATIONAL, no boot-up / loss / reset heard   yes (the standby joined a running bus)
  since the node began to be listened to
NMT pre-operational / stop                     unchanged (the operator's state of a started node)
boot-up, loss, NMT reset / reset communication no (the other master configures it again)
=============================================  ================================================

What the node does with it (its diagnostics, an adoption) is done by the functions below,
which ``Node`` calls.

Imports: bus.node.lifecycle_actions (its states), bus.events, bus.node.node (the type
only), canopen.states. No I/O, no clock.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gateway.bus.events import HealthChanged, Output
from gateway.bus.node.lifecycle_actions import LifecycleState
from gateway.canopen.states import NmtState

if TYPE_CHECKING:
    from gateway.bus.node.node import Node

#: the NMT states a started node may be adopted in (CiA 301 7.3.2.2: the NMT slave states
#: reached by a command without a reset)
ADOPTABLE = (NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL, NmtState.STOPPED)


class HeardLife:
    """What a listening node heard of its life under the other master (table above)."""

    def __init__(self) -> None:
        self.started = False
        #: a boot-up, loss or reset was heard since listening began: from then on only a heard
        #: NMT start says the node was started (its OPERATIONAL state alone no longer does)
        self.restarted = False

    def stood_down(self, state: LifecycleState) -> None:
        """This gateway stood down from mastering the node, its lifecycle in ``state``: the
        node is started if it had it operational (already listening: nothing changes)."""
        if state is not LifecycleState.LISTENING:
            self.started, self.restarted = state is LifecycleState.OPERATIONAL, False

    def on_nmt_command(self, command: str) -> None:
        if command == "start":
            self.started = True
        elif command in ("reset", "reset-comm"):
            self.started, self.restarted = False, True

    def on_state(self, state: NmtState) -> None:
        """A valid heartbeat / guarding answer reporting ``state``."""
        if state == NmtState.OPERATIONAL and not self.restarted:
            self.started = True

    def on_restart(self) -> None:
        """A boot-up or a loss: the other master configures the node again."""
        self.started, self.restarted = False, True

    def lifecycle(self, alive: bool) -> str:
        """The lifecycle the standby reports, as the active gateway's would read: operational
        when heard started and alive, waiting when not alive, else unknown (being configured,
        or refused: the standby cannot tell)."""
        if not alive:
            return str(LifecycleState.WAITING)
        return str(LifecycleState.OPERATIONAL) if self.started else "unknown"

    def adopt_in(self, alive: bool, state: NmtState) -> NmtState | None:
        """At a take-over: the NMT state the node is adopted in, None to configure it."""
        return state if self.started and alive and state in ADOPTABLE else None


# -- what the node does with what it heard (``Node`` calls these)


def adopted(node: Node, state: NmtState | None, now: float) -> list[Output]:
    """A take-over adopted the node in ``state`` (None: not adopted): guarding expects that
    state and goes on with the toggle the node expects next (every answer was followed)."""
    if state is None:
        return []
    node.supervision.expect_state(state)
    out: list[Output] = []
    for f in node.features:
        out += f.on_adopted(node, now)
    return out


def report_heard(node: Node) -> list[Output]:
    """While listening, the lifecycle the node reports is what was heard (``HeardLife``)."""
    word = node.heard.lifecycle(node.health.alive)
    if node.health.lifecycle == word:
        return []
    node.health.lifecycle = word
    return [HealthChanged("state")]


def on_state(node: Node, state: NmtState, now: float) -> list[Output]:
    """A valid heartbeat / guarding answer heard while listening."""
    node.heard.on_state(state)
    h = node.health
    out: list[Output] = []
    if state == NmtState.OPERATIONAL and h.fresh_since is None and h.alive:
        # started by another master; no boot-up since it was heard operational, so what it
        # sends from now on is fresh
        h.fresh_since = now
        out.append(HealthChanged("state"))
    return out + report_heard(node)


def on_restart(node: Node) -> list[Output]:
    """A boot-up or a loss heard while listening: the other master configures it again."""
    node.heard.on_restart()
    return report_heard(node)
