"""The gateway's one vocabulary for node states: NMT states, guarding-bit link states and the
NMT command table.

Every part of the gateway (the master and its supervision machines, the process image, Modbus,
Zenoh, the simulator) uses these enums; none defines its own.

Imports: cia301 (the NMT command specifiers) and the standard library.
"""

from __future__ import annotations

from enum import IntEnum

from canopen_gateway.canopen import cia301


class NmtState(IntEnum):
    """NMT state of a node (DS-301; SGH10 manual 4.2, 4.5.2, 4.5.3).

    The values are the state byte of a heartbeat / node-guarding answer; ``UNKNOWN`` is the
    gateway's own: the state is not known (never heard of, lost, or the bus is down).
    """

    UNKNOWN = -1
    BOOTUP = 0x00  # SGH10 manual 4.2.2: the boot-up message carries 00h (initialising)
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F  # 127


#: States a heartbeat or a guarding answer may report (SGH10 manual 4.5.2/4.5.3: 4, 5, 127).
REPORTED_STATES = frozenset({NmtState.STOPPED, NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL})


class LinkState(IntEnum):
    """Process-data link by the guarding bit (AP05 manual 5.5.5); Modbus IR 10 codes."""

    NOT_USED = 0
    OK = 1
    FAULT = 2
    UNKNOWN = 3  # nothing sent yet, or no echo seen yet

    def __str__(self) -> str:
        return self.name.lower()


#: NMT command names and command specifiers: defined in cia301, named here for the modules
#: that speak of node states (the CLI, Modbus HR 0, Zenoh and the master read it).
NMT_COMMANDS = cia301.NMT_COMMANDS
NMT_BY_CODE = cia301.NMT_BY_CODE
