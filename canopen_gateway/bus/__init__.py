"""The CANopen side of the gateway: the driver (python-can, its reader and sender threads), the
master (the event loop's driver of every node) of the nodes ``canopen_gateway.device`` resolved, the
per-node owner (``node/``), SDO (``sdo/``), error control
(``error_control/``), LSS (``lss/``), EMCY and the master's own periodic frames.

Nothing in this package imports a northbound module (modbus, zenoh_bridge, web, ascii).

Imports: nothing (its modules are imported by name).
"""
