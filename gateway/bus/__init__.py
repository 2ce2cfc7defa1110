"""The CANopen side of the gateway: bus driver, process-data codecs and the master's protocol
state machines (supervision, node lifecycle, EMCY, LSS, SDO abort texts).

Nothing in this package imports a northbound module (modbus, zenoh_bridge).
"""
