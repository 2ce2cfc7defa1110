"""A node that only listens (lifecycle LISTENING: a pair's standby): what it heard of the node's
life under the other master, and what a take-over makes of it.

Rule 1: decisions from what is heard now, not from history. The standby sends nothing, so
everything it knows of a node it heard; what it did not hear it does not guess. A loss (the
node silent for its supervision time: the node gone, or this gateway deaf) says nothing of a
restart: only the node's own boot-up or a reset command heard does. After a loss the node is
listened to as by a gateway that just joined. Rule 2: at a take-over a node is adopted as it
runs unless it is heard being configured; the operator's NMT state is kept; a node that fell
out of OPERATIONAL by itself (a device-side timeout: no command heard) is started again with
NMT start only (its configuration is kept: no SDO).

``HeardLife`` follows ``LIFE`` (what each thing heard makes of the node's life; rows are what
was heard, columns the life before)::

    heard                          unknown  started  held     fell     quiet    booting
    NMT start (to it or to all)    started  started  started  started  started  started
    NMT pre-operational / stop     unknown  held     held     held     quiet    booting
    boot-up, NMT reset (-comm)     booting  booting  booting  booting  booting  booting
    OPERATIONAL reported           started  started  held**   started  started  booting*
    PRE-OPERATIONAL / STOPPED      quiet    fell     held     fell     quiet    booting
    lost (silent: gone, or deaf)   unknown  unknown  held     unknown  unknown  unknown
    another client's SDO request   unknown  started  held     booting  booting  booting

``started`` runs under the other master; ``held`` is the operator's pre-operational / stopped
state of a started node (the command heard); ``fell`` left OPERATIONAL with no command heard;
``quiet`` first heard pre-operational / stopped with no cause heard (this gateway joined, or
came back, after it); ``booting`` is being configured by the other master (a boot-up or reset
heard, or its SDO requests to a node not known started). (*) A booting node heard OPERATIONAL
is started once no SDO request to it was heard for ``SETTLE_S`` (its NMT start may have been
missed: a frame lost). (**) Only a start ends the operator's hold: a heartbeat sent as the
command went out still says OPERATIONAL; a held node is adopted in the state it reports.

At a take-over (``take_over``): ``started`` and ``held`` are adopted in the state they report
(nothing sent), ``fell`` is adopted and sent NMT start (nothing else), ``quiet`` is adopted as
it is when an active master was heard keeping it so (the operator's state, missed), else, and
``booting`` / not alive, found and configured as usual; ``unknown`` (nothing heard of it since
a loss or an outage) or ``held`` and lost, when a master was heard, waits to be heard: OPERATIONAL (or held, as the
operator left it) it resumes as it runs, else it is found and configured as usual. A loss
does not end the operator's hold: only a start or a boot-up does. For a while after an
adoption (``FALL_WATCH``: the node's next report) a node that reports a fall with no command of
ours is started the same way (its device-side timeout expired during the take-over).

A gateway that stands down keeps what it knew of each node (``stood_down``), unless it comes
back from its own outage (cut off, unable to send): then it listens as a fresh joiner.

Imports: bus.node.lifecycle_actions (its states), bus.events, bus.node.node and
device.settings (the types only), canopen.cia301, canopen.states. No I/O, no clock.
"""

from __future__ import annotations

import logging
from enum import StrEnum
from typing import TYPE_CHECKING

from canopen_gateway.bus.events import HealthChanged, Note, Output, Send
from canopen_gateway.bus.node.lifecycle_actions import LifecycleState
from canopen_gateway.canopen.cia301 import COB_NMT, NmtCommand
from canopen_gateway.canopen.states import NmtState

if TYPE_CHECKING:
    from canopen_gateway.bus.node.node import Node
    from canopen_gateway.device.settings import NodeSettings

#: the NMT states a node may be adopted in (CiA 301 7.3.2.2: the NMT slave states reached by a
#: command without a reset)
ADOPTABLE = (NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL, NmtState.STOPPED)
#: a booting node heard OPERATIONAL with no SDO request to it for this long is started
SETTLE_S = 2.0


class Life(StrEnum):
    """What the standby heard of a node's life (the columns of ``LIFE``)."""

    UNKNOWN = "unknown"
    STARTED = "started"
    HELD = "held"
    FELL = "fell"
    QUIET = "quiet"
    BOOTING = "booting"


_U, _S, _H, _F, _Q, _B = Life.UNKNOWN, Life.STARTED, Life.HELD, Life.FELL, Life.QUIET, Life.BOOTING
#: heard -> (life before -> life after), the table of the module docstring
LIFE: dict[str, dict[Life, Life]] = {
    "start": dict.fromkeys(Life, _S),
    "hold": {_U: _U, _S: _H, _H: _H, _F: _H, _Q: _Q, _B: _B},
    "restart": dict.fromkeys(Life, _B),
    "operational": {_U: _S, _S: _S, _H: _H, _F: _S, _Q: _S, _B: _B},
    "fallen": {_U: _Q, _S: _F, _H: _H, _F: _F, _Q: _Q, _B: _B},
    "lost": {**dict.fromkeys(Life, _U), _H: _H},  # the operator's hold ends by a start or a boot-up
    "sdo": {_U: _U, _S: _S, _H: _H, _F: _B, _Q: _B, _B: _B},
}
#: what an NMT command heard is in ``LIFE``
_COMMANDS = {"start": "start", "preop": "hold", "stop": "hold", "reset": "restart", "reset-comm": "restart"}
#: what the standby reports as the node's lifecycle, by life (alive)
_MANAGED = (Life.STARTED, Life.HELD, Life.FELL)


class HeardLife:
    """What a listening node heard of its life under the other master (``LIFE``)."""

    def __init__(self) -> None:
        self.life = Life.UNKNOWN
        #: booting and heard OPERATIONAL: since when, with no SDO request to it since
        self._settling_s: float | None = None
        #: after an adoption: until when a fall reported with no command of ours is started
        self.fall_watch_until_s: float | None = None

    @property
    def started(self) -> bool:
        """Managed by the other master: started, or held / fallen since."""
        return self.life in _MANAGED

    def _hear(self, what: str) -> None:
        self.life = LIFE[what][self.life]
        if self.life is not Life.BOOTING:
            self._settling_s = None

    def fresh(self) -> None:
        """This gateway comes back from its own outage: it listens as a fresh joiner."""
        self.life, self._settling_s, self.fall_watch_until_s = Life.UNKNOWN, None, None

    def stood_down(self, state: LifecycleState, nmt: NmtState, fresh: bool = False) -> None:
        """This gateway stood down from mastering the node, its lifecycle in ``state`` and the
        node in ``nmt``: what it did to the node it knows (already listening: nothing changes).
        ``fresh``: it comes back from its own outage, and knows nothing (a fresh joiner)."""
        if fresh:
            self.fresh()
            return
        if state is LifecycleState.LISTENING:
            return
        self.fall_watch_until_s = None
        if state is LifecycleState.OPERATIONAL:
            self.life = _S if nmt == NmtState.OPERATIONAL else _H
        else:
            self.life = _B if state is not LifecycleState.WAITING else _U

    def on_nmt_command(self, command: str) -> None:
        """An NMT command to the node (or to all) heard, or sent by this gateway."""
        self.fall_watch_until_s = None
        what = _COMMANDS.get(command)
        if what is not None:
            self._hear(what)

    def on_state(self, state: NmtState, now: float) -> None:
        """A valid heartbeat / guarding answer reporting ``state``."""
        if state == NmtState.OPERATIONAL:
            if self.life is Life.BOOTING:
                if self._settling_s is None:
                    self._settling_s = now
                elif now - self._settling_s >= SETTLE_S:
                    self.life, self._settling_s = Life.STARTED, None
                return
            self._hear("operational")
        elif state in ADOPTABLE:
            self._settling_s = None if self.life is Life.BOOTING else self._settling_s
            self._hear("fallen")

    def on_restart(self) -> None:
        """A boot-up heard: the other master configures the node again."""
        self._hear("restart")

    def on_lost(self) -> None:
        """The node fell silent (gone, or this gateway deaf): nothing is known of it now."""
        self._hear("lost")

    def on_sdo_request(self, now: float) -> None:
        """Another client's SDO request to the node (the other master's, while listening)."""
        self._hear("sdo")
        if self.life is Life.BOOTING and self._settling_s is not None:
            self._settling_s = now

    def lifecycle(self, alive: bool) -> str:
        """The lifecycle the standby reports, as the active gateway's would read: operational
        when managed and alive, waiting when not alive, else unknown (being configured,
        refused, or its cause not heard: the standby cannot tell)."""
        if not alive:
            return str(LifecycleState.WAITING)
        return str(LifecycleState.OPERATIONAL) if self.started else "unknown"

    def adopt_in(self, alive: bool, state: NmtState, master_heard: bool) -> NmtState | None:
        """At a take-over: the NMT state the node is adopted in, None to configure it.
        ``master_heard``: an active master was heard since this gateway began listening."""
        if not alive or state not in ADOPTABLE:
            return None
        if self.started or (self.life is Life.QUIET and master_heard):
            return state
        return None


# -- what the node does with what it heard (``Node`` calls these)


def _start_again(node: Node, why: str) -> list[Output]:
    """NMT start, nothing else: the node keeps its configuration (CiA 301 7.2.8.3.1)."""
    node.heard.fall_watch_until_s = None
    node.supervision.on_nmt_command("start")
    return [
        Send(COB_NMT, bytes([NmtCommand.START, node.node_id])),
        Note(logging.WARNING, f"node {node.name} (id {node.node_id}) {why}: NMT start, configuration kept"),
    ]


def take_over(node: Node, now: float, master_heard: bool) -> tuple[NmtState | None, list[Output], bool]:
    """A take-over: the NMT state the node is adopted in (None: found and configured as usual,
    or, nothing heard of it since listening began, taken as it runs once heard OPERATIONAL:
    ``node.lifecycle.resumable``), and what goes out to it (an NMT start for one that fell:
    nothing else)."""
    h = node.health
    adopt = node.heard.adopt_in(h.alive, h.nmt_state, master_heard)
    if adopt is None:  # nothing heard of it since a loss (a master was): waited for, not probed
        return None, [], master_heard and node.heard.life in (Life.UNKNOWN, Life.HELD)
    if adopt == NmtState.OPERATIONAL and node.heard.life is Life.STARTED:
        # adopted running (not held by the operator): a fall reported soon is the take-over's
        node.heard.fall_watch_until_s = now + fall_watch_s(node)
    if node.heard.life is Life.FELL:
        return adopt, _start_again(node, f"found {adopt.name.lower()} at the take-over, fallen by itself"), False
    return adopt, [], False


def resume_wait_s(s: NodeSettings) -> float:
    """How long a pair's node found by a probe waits to be heard before it is configured: two of
    its heartbeat periods, at least 0.3 s (a healed split resolves within one logical heartbeat)."""
    return max(0.3, 2 * s.heartbeat_ms / 1000.0) if s.supervision == "heartbeat" else 1.0


def fall_watch_s(node: Node) -> float:
    """How long after an adoption the node's next report may still tell a fall of the take-over:
    its supervision time (heartbeat consumer or life time), at least one second."""
    s = node.s
    if s.supervision == "heartbeat" and s.heartbeat_ms:
        return max(1.0, s.heartbeat_ms * s.heartbeat_multiple / 1000.0)
    if s.supervision == "guarding":
        return max(1.0, s.life_time_ms / 1000.0)
    return 1.0


def watch_fall(node: Node, state: NmtState, now: float) -> list[Output]:
    """An adopted node reports ``state``: a fall within the watch, no command of ours since,
    is a device-side timeout of the take-over: NMT start again."""
    until = node.heard.fall_watch_until_s
    if until is None:
        return []
    if now > until or node.lifecycle.state is not LifecycleState.OPERATIONAL:  # over, or lost since
        node.heard.fall_watch_until_s = None
        return []
    if state in (NmtState.PRE_OPERATIONAL, NmtState.STOPPED):
        return _start_again(node, f"fell {state.name.lower()} by itself after the take-over")
    return []


def commanded(node: Node, command: str) -> None:
    """An NMT command to the node, heard while listening or sent by this gateway (a node of
    ours running is started: the operator's pre-operational / stop holds it)."""
    lc = node.lifecycle
    if not node.listening and (lc.state is LifecycleState.OPERATIONAL or lc.resumable):
        node.heard.life = Life.STARTED  # ours and started (running, or lost while it ran)
    node.heard.on_nmt_command(command)


def resumes_in(node: Node, state: NmtState) -> bool:
    """A pair's node waiting (lost, or not found yet), heard with no boot-up seen, resumes in
    ``state``: OPERATIONAL (the pair started it: a healed split, a member that took the bus at
    a first start while the other ran it), or, lost while it ran, the state the operator held
    it in."""
    if state == NmtState.OPERATIONAL:
        return True
    return node.lifecycle.resumable and node.heard.life is Life.HELD and state in ADOPTABLE


def another_master(node: Node, now: float) -> None:
    """This gateway, active, met another master (a healed split, a lost claim): a node of
    ours waiting (lost, or not found yet) may be that master's, running: it waits to be heard
    (OPERATIONAL: it resumes) instead of being found and configured. What that master sent it
    is not known (the node waiting, or resumed a moment ago: ``OutputImage.hold``): its RPDOs
    are unknown until heard or written."""
    lc = node.lifecycle
    if node.listening:
        return
    if lc.state is LifecycleState.WAITING or node.outputs.holding(now):
        node.outputs.forget()
    if lc.state is LifecycleState.WAITING and lc.may_probe(float("inf")):
        lc.resumable = True


def heard_invalid(node: Node, byte: int, now: float) -> list[Output]:
    """An answer that is not valid (a guarding toggle or state error) still says the state the
    node is in: a guarded node that fell is heard so (listening, or adopted and watched)."""
    state = byte & 0x7F
    if state not in ADOPTABLE:
        return []
    if node.listening:
        node.heard.on_state(NmtState(state), now)
        return report_heard(node)
    return watch_fall(node, NmtState(state), now)


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
    node.heard.on_state(state, now)
    h = node.health
    out: list[Output] = []
    if state == NmtState.OPERATIONAL and h.fresh_since is None and h.alive:
        # started by another master; no boot-up since it was heard operational, so what it
        # sends from now on is fresh
        h.fresh_since = now
        out.append(HealthChanged("state"))
    return out + report_heard(node)


def on_restart(node: Node) -> list[Output]:
    """A boot-up heard while listening: the other master configures it again."""
    node.heard.on_restart()
    return report_heard(node)


def on_sdo_heard(node: Node, now: float) -> list[Output]:
    """Another client's SDO request to the node heard while listening."""
    node.heard.on_sdo_request(now)
    return report_heard(node)


def on_lost(node: Node) -> list[Output]:
    """The node lost while listening (gone, or this gateway deaf): nothing known of it now."""
    node.heard.on_lost()
    return report_heard(node)
