"""CANopen to Modbus TCP and Zenoh edge gateway."""

__version__ = "0.1.0"
