"""The words of a hot-standby pair's role changes, as the log says them (``pair: standby ->
negotiating (the active master was silent for 300 ms)``): one place for the reason of each
row of the role machine's table (``flying_master.TRANSITIONS``).

Imports: bus.pair.protocol (its vocabulary) and the standard library.
"""

from __future__ import annotations

from canopen_gateway.bus.pair.protocol import Claim, Heard, PairTiming

_REASONS: dict[Heard, str] = {
    Heard.NEGOTIATION: "another gateway negotiates (72h)",
    Heard.DETECTION_OVER: "no active master heard",
    Heard.SLOT_OVER: "no other claim within the time slot",
    Heard.LINK_LOST: "this gateway's CAN bus is down",
    Heard.CANNOT_SEND: "this gateway cannot send (its driver says so): no fail-back onto it",
    Heard.BUS_HEARD: "the bus is heard again: listen before joining",
    Heard.STALLED: (
        "this gateway did not run for longer than the take-over time: the other may be active"
    ),
    Heard.MET_AFTER_CUT: (
        "another master met after this gateway heard nothing for a while: no fail-back onto it"
    ),
    Heard.LOGICAL_HEARTBEAT: "the active master is heard",
    Heard.FORCE: "the active master is heard",
    Heard.STEPPED_DOWN: "the active member handed the bus over (its heartbeat says it stopped mastering)",
    Heard.LEAVING: "this gateway stops: the bus is handed over to the standby",
}


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.0f} ms"


def reason(heard: Heard, timing: PairTiming, peer: Claim | None, conflict: str | None) -> str:
    """Why the role changed on ``heard``: a line for the log and the role listeners."""
    who = f"priority {peer.priority}, node {peer.node_id}" if peer else "another gateway"
    if heard is Heard.ACTIVE_SILENT:
        return f"the active master was silent for {_ms(timing.takeover_s)}"
    if heard is Heard.DEAF:
        return f"nothing heard on the bus for {_ms(timing.takeover_s)}: cut off"
    if heard is Heard.UNANSWERED:
        return (
            f"another master ({who}) met and this gateway's 75h drew no answer in "
            f"{_ms(timing.answer_s)}: its frames do not reach the bus; no fail-back onto it"
        )
    if heard is Heard.OWN_ID:
        return f"{conflict}: this gateway stays out"
    if heard in (Heard.BETTER_CLAIM, Heard.OUTBID):
        return f"an active master that wins ({who}) is heard"
    if heard is Heard.WORSE_CLAIM:
        return f"an active master ({who}) is heard: no fail-back"
    return _REASONS.get(heard, heard.value)
