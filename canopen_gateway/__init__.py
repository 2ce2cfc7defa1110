"""CANopen to Modbus TCP and Zenoh edge gateway.

Imports: nothing (the version only).
"""

__version__ = "0.1.0"
