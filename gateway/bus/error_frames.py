"""What a CAN controller says in an error frame, by the SocketCAN layout (linux/can/error.h,
which python-can's other backends follow too): the error class bits in the CAN-ID, the
controller's status in data byte 1. Pure: a frame in, the state it reports out; the bus driver
(``bus.driver``) keeps the bus state.

Imports: python-can (the frame's type) only.
"""

from __future__ import annotations

import can

# linux/can/error.h: error classes (CAN-ID bits of an error frame) and controller status bits
CAN_ERR_CRTL = 0x00000004  # controller problems, details in data[1]
CAN_ERR_BUSOFF = 0x00000040  # bus off
CAN_ERR_RESTARTED = 0x00000100  # controller restarted
CAN_ERR_CRTL_RX_PASSIVE = 0x10  # reached error passive status on receive
CAN_ERR_CRTL_TX_PASSIVE = 0x20  # reached error passive status on transmit
CAN_ERR_CRTL_ACTIVE = 0x40  # recovered to error active state

#: the report of a controller error active again (restarted, or recovered)
ERROR_ACTIVE = "error active"


def controller_report(msg: can.Message) -> str | None:
    """``bus off``, ``error passive (transmit)`` / ``(receive)``, ``ERROR_ACTIVE``, or None
    for an error frame that says none of these."""
    cls = msg.arbitration_id
    data = bytes(msg.data).ljust(8, b"\0")
    ctrl = data[1] if cls & CAN_ERR_CRTL else 0
    if cls & CAN_ERR_BUSOFF:
        return "bus off"
    if ctrl & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
        return f"error passive ({'transmit' if ctrl & CAN_ERR_CRTL_TX_PASSIVE else 'receive'})"
    if cls & CAN_ERR_RESTARTED or ctrl & CAN_ERR_CRTL_ACTIVE:
        return ERROR_ACTIVE
    return None
