"""The simulated device's NMT slave: what an NMT command asks, which node id a reset adopts and
which objects it reloads (SGH10 manual 000/003 section numbers). Functions of their inputs: the
node (``SimNode._initialise``, ``SimNode.set_nmt_state``) applies what they return.

- NMT commands (4.2.1): COB 0x000 ``[cs, id]``, id 0 = all: 01 start, 02 stop, 80
  pre-operational, 81 reset node, 82 reset communication (``command``).
- initialisation (4.2.1.1, 4.2.2): INITIALISATION, the boot-up 0x700+id data 00, then
  PRE-OPERATIONAL. ``power``: every object from its EDS default overlaid with what 1010h stored,
  the node id the store holds (LSS / Auto-ID) or the configured one (``node_id_after_reset``),
  errors and faults cleared, the stored calibration applied. ``node`` (reset node, 81h): every
  object reloaded; ``communication`` (reset communication, 82h): 1000h-1FFFh reloaded; both
  adopt a pending node id, keep 1001h / 1003h (``reload_objects``) and show the faults still
  active again.

Imports: canopen_gateway.canopen.cia301 (NMT commands), canopen_gateway.canopen.states (NmtState), sim.objects. Nothing of bus/,
modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from typing import Literal

from canopen_gateway.canopen.cia301 import NmtCommand
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.sim.objects import ObjectValues, PersistentStore

ResetKind = Literal["power", "node", "communication"]

#: the NMT commands that change the state without a reset (4.2.1)
NMT_COMMAND_STATES: dict[int, NmtState] = {
    NmtCommand.START: NmtState.OPERATIONAL,
    NmtCommand.STOP: NmtState.STOPPED,
    NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
}
#: the NMT commands that reset the node (4.2.1, 4.2.2)
NMT_COMMAND_RESETS: dict[int, ResetKind] = {
    NmtCommand.RESET_NODE: "node",
    NmtCommand.RESET_COMMUNICATION: "communication",
}
#: the store's sub-index of 1010h / 1011h each reset reloads (SGH10 manual 4.7.2.11/12: 1 all
#: objects, 2 communication objects 1000h-1FFFh)
RELOADED_BY_RESET: dict[ResetKind, int] = {"power": 1, "node": 1, "communication": 2}
#: what a reset node / communication keeps: the error register and the error history (4.2.2)
KEPT_BY_RESET = (0x1001, 0x1003)


def command(cs: int, target: int, node_id: int) -> ResetKind | NmtState | None:
    """What the NMT command ``[cs, target]`` asks of node ``node_id`` (4.2.1; target 0 addresses
    every node): a reset, a state, or nothing."""
    if target not in (0, node_id):
        return None
    reset = NMT_COMMAND_RESETS.get(cs)
    return reset if reset is not None else NMT_COMMAND_STATES.get(cs)


def node_id_after_reset(
    kind: ResetKind, *, configured: int, current: int, pending: int | None, stored: int | None
) -> int:
    """The node id a reset adopts: at power-on the stored one (LSS / Auto-ID) or the configured
    one; at a reset node / communication a pending one, else the current one. A pending id is
    gone after any reset."""
    if kind == "power":
        return stored or configured
    return pending if pending is not None else current


def reload_objects(values: ObjectValues, store: PersistentStore, node_id: int, kind: ResetKind) -> None:
    """The objects a reset reloads: EDS defaults overlaid with what 1010h stored; a reset node /
    communication keeps 1001h and 1003h."""
    keep = {}
    if kind != "power":
        keep = {k: values.get(*k) for k in values.keys() if k[0] in KEPT_BY_RESET}
    values.load_defaults(node_id, store, RELOADED_BY_RESET[kind])
    for k, v in keep.items():
        values.set(k[0], k[1], v)
