"""The command service, split by role: ``service`` (``CommandService``, the one way south and
the only writer of device values), ``validation`` (the checks of a value before it is sent),
``sdo_cache`` (the SDO values read north) and ``bus_inquiry`` (LSS inquire, the bus scan).

Imports: commands.service, commands.validation. Never modbus/ or zenoh_bridge/.
"""

from canopen_gateway.commands.service import CommandService, NodeInfo
from canopen_gateway.commands.validation import (
    REAL32_MAX,
    SDO_TYPES,
    bit_names,
    check_sdo_type,
    check_value,
    type_range,
    writable_mask,
)

__all__ = [
    "REAL32_MAX",
    "SDO_TYPES",
    "CommandService",
    "NodeInfo",
    "bit_names",
    "check_sdo_type",
    "check_value",
    "type_range",
    "writable_mask",
]
