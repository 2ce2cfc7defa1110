"""The CiA 301 pre-defined connection set (7.3.3) in words: what a COB-ID is, who sent it.

``describe_cob_id(0x181)`` is ``TPDO1 of node id 1``; ``talking_node_id(0x181)`` is 1 (a node
sends its own TPDOs, EMCY, SDO answers and heartbeat). Pure functions of the COB-ID.

Imports: canopen.cia301 (the COB-IDs and the table of the connection set) and the standard library only.
"""

from __future__ import annotations

from canopen_gateway.canopen.cia301 import (
    COB_EMCY,
    COB_LSS_MASTER,
    COB_LSS_SLAVE,
    COB_NMT,
    COB_NMT_EC,
    COB_SDO_TX,
    COB_SYNC,
    COB_TIME,
    COB_TPDO,
    PREDEFINED_FUNCTIONS,
)

#: CiA 301 7.3.3, pre-defined connection set: function code (COB-ID bits 10..7) -> name (the
#: device's SDO response said as the bus logs say it: an answer)
_FUNCTIONS = {**PREDEFINED_FUNCTIONS, COB_SDO_TX: "SDO answer"}
#: functions a node sends itself: its id is talking when we see them
_SENT_BY_NODE = frozenset({COB_EMCY, *COB_TPDO, COB_SDO_TX, COB_NMT_EC})


def describe_cob_id(cob_id: int) -> str:
    """``TPDO1 of node id 1`` for 0x181; ``NMT``, ``SYNC``, ``LSS``; else ``COB-ID 0x7A0``."""
    if cob_id == COB_NMT:
        return "NMT"
    if cob_id == COB_SYNC:
        return "SYNC"
    if cob_id == COB_TIME:
        return "TIME"
    if cob_id in (COB_LSS_SLAVE, COB_LSS_MASTER):
        return "LSS"
    base, node_id = cob_id & 0x780, cob_id & 0x7F
    name = _FUNCTIONS.get(base)
    if name is None or node_id == 0:
        return f"COB-ID 0x{cob_id:03X}"
    return f"{name} of node id {node_id}"


def talking_node_id(cob_id: int) -> int | None:
    """The node id that sent this frame, when its COB-ID is one a node sends itself."""
    base, node_id = cob_id & 0x780, cob_id & 0x7F
    if base in _SENT_BY_NODE and node_id:
        return node_id
    return None
