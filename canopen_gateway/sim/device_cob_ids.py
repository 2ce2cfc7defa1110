"""The COB-IDs a simulated device receives and sends on, read from its current objects (SGH10
manual 000/003 4.1): its EMCY COB-ID from 1014h (``emcy_cob``); the valid TPDOs (an RTR asks for
one) and RPDOs of 1400h-1BFFh, SYNC from 1005h (80h where the file gives no value), and its
default SDO server's request and response COB-IDs, 600h / 580h + node id whatever 1200h holds
(SGH10 manual 4.7.2.16: "The COB IDs cannot be changed"; the predefined connection set; a DCF
written for another node id holds that node's).

``receive_map`` is derived again whenever a COB-ID, a PDO parameter or the node id changes (the
node drops its copy then).

Imports: canopen_gateway.canopen.cia301 (COB-IDs and their bits), sim.objects, sim.pdo. Nothing of bus/,
modbus/, zenoh_bridge/.
"""

from __future__ import annotations

from collections.abc import Iterable

import canopen_gateway.sim.pdo as pdo
from canopen_gateway.canopen.cia301 import (
    COB_EMCY,
    COB_ID_INVALID,
    COB_ID_MASK_11BIT,
    COB_ID_MASK_29BIT,
    COB_SDO_RX,
    COB_SDO_TX,
    COB_SYNC,
)
from canopen_gateway.sim.objects import ObjectValues


def sdo_rx_cob(node_id: int) -> int:
    """The COB-ID of the SDO requests the device answers (SGH10 manual 4.7.2.16: 600h + node id)."""
    return COB_SDO_RX + node_id


def sdo_tx_cob(node_id: int) -> int:
    """The COB-ID of the device's SDO responses (SGH10 manual 4.7.2.16: 580h + node id)."""
    return COB_SDO_TX + node_id


def emcy_cob(values: ObjectValues, node_id: int) -> int | None:
    """The COB-ID of the device's EMCY frames from 1014h (80h + node id where the file has no
    1014h); None while 1014h bit 31 says EMCY is not valid (SGH10 manual 4.5.1)."""
    if not values.has(0x1014, 0):
        return COB_EMCY + node_id
    cob = int(values.get(0x1014, 0, 0))
    return None if cob & COB_ID_INVALID else cob & COB_ID_MASK_29BIT


def receive_map(
    values: ObjectValues, node_id: int, tpdos: Iterable[int], rpdos: Iterable[int]
) -> dict[int, tuple[str, int]]:
    """COB-ID -> (``tpdo`` | ``rpdo`` | ``sync`` | ``sdo``, PDO number or 0)."""
    m: dict[int, tuple[str, int]] = {}
    for n in tpdos:
        cob = pdo.cob_id(values, "tpdo", n)
        if not cob & COB_ID_INVALID:
            m[cob & COB_ID_MASK_29BIT] = ("tpdo", n)
    for n in rpdos:
        cob = pdo.cob_id(values, "rpdo", n)
        if not cob & COB_ID_INVALID:
            m[cob & COB_ID_MASK_29BIT] = ("rpdo", n)
    sync = int(values.get(0x1005, 0) or COB_SYNC) & COB_ID_MASK_11BIT
    m[sync or COB_SYNC] = ("sync", 0)
    m[sdo_rx_cob(node_id)] = ("sdo", 0)
    return m
