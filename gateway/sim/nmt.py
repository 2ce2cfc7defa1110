"""The simulated device's NMT slave: initialisation (power-on and the two resets) and the NMT
commands (SGH10 manual 000/003 section numbers).

Module-level functions taking the ``SimNode``:

- ``initialise(node, kind, now)`` (4.2.1.1, 4.2.2): INITIALISATION, the boot-up 0x700+id data
  00, then PRE-OPERATIONAL. ``power``: every object from its EDS default overlaid with what 1010h
  stored, the node id the store holds (LSS / Auto-ID) or the configured one, errors and faults
  cleared, the stored calibration applied. ``node`` (reset node, 81h): every object reloaded;
  ``communication`` (reset communication, 82h): 1000h-1FFFh reloaded; both adopt a pending node
  id, keep 1001h / 1003h and show the faults still active again.
- ``on_nmt_command(node, cs, target, now)`` (4.2.1): COB 0x000 ``[cs, id]``, id 0 = all: 01
  start, 02 stop, 80 pre-operational, 81 reset node, 82 reset communication.

Imports: gateway.cia301 (NMT commands, COB_NMT_EC), gateway.states (NmtState); sim.node for
types only. Nothing of bus/, modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from gateway.cia301 import (
    COB_NMT_EC,
    NMT_ENTER_PRE_OPERATIONAL,
    NMT_RESET_COMMUNICATION,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
)
from gateway.states import NmtState

if TYPE_CHECKING:
    from gateway.sim.node import SimNode

ResetKind = Literal["power", "node", "communication"]

#: the NMT commands that change the state without a reset (4.2.1)
NMT_COMMAND_STATES = {
    NMT_START: NmtState.OPERATIONAL,
    NMT_STOP: NmtState.STOPPED,
    NMT_ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
}


def initialise(node: SimNode, kind: ResetKind, now: float) -> None:
    """INITIALISATION (SGH10 manual 4.2.1.1), boot-up message, then PRE-OPERATIONAL."""
    node.powered = True
    node.last_reset = kind
    node.nmt_state = NmtState.BOOTUP
    values = node.values
    if kind == "power":
        node.motion.start(now)
        node.node_id = node.store.node_id or node.configured_node_id
        node.pending_node_id = None
        values.load_defaults(node.node_id, node.store, 1)
        node.emcy.reset()
        node.faults.clear()
        node.position_offset = node.store.position_offset or 0
        if node.position_offset:
            for obj in node.hints.offset_objects:
                if values.has(*obj):
                    values.set(*obj, -node.position_offset)
    else:
        if node.pending_node_id is not None:
            node.node_id = node.pending_node_id
            node.pending_node_id = None
        keep = {k: values.get(*k) for k in values.keys() if k[0] in (0x1001, 0x1003)}
        values.load_defaults(node.node_id, node.store, 1 if kind == "node" else 2)
        for k, v in keep.items():
            values.set(k[0], k[1], v)
    node.listening_changed()
    node.sdo.reset()
    node.error_control.reset()
    node.tpdo_producer.reset()
    node.invalidate_process()
    if kind != "power":  # the device still has its faults: show them again
        for name, active in node.faults.items():
            if active:
                node.hint_fault_bits(name, True)
    for b in node.features:
        b.on_boot(now)
    node.send(COB_NMT_EC + node.node_id, b"\x00")  # boot-up (4.2.2), unless silenced
    node.nmt_state = NmtState.PRE_OPERATIONAL
    node.error_control.schedule_heartbeat(now)
    for b in node.features:
        b.on_nmt(int(node.nmt_state), now)


def on_nmt_command(node: SimNode, cs: int, target: int, now: float) -> None:
    """An NMT command ``[cs, target]`` (4.2.1); target 0 addresses every node."""
    if target not in (0, node.node_id):
        return
    if cs == NMT_RESET_NODE:
        initialise(node, "node", now)
        return
    if cs == NMT_RESET_COMMUNICATION:
        initialise(node, "communication", now)
        return
    new = NMT_COMMAND_STATES.get(cs)
    if new is not None:
        node.set_nmt_state(new, now)
