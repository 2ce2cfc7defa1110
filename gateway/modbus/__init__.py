"""The Modbus TCP adapter: the server, the datastore that serves the process image and writes
through the command service, the register encoding, the output watchdog, Modbus/TCP Security
and the device identification. The register map itself is shared (``northbound.regmap``).

Imports: commands, northbound, image, config, errors, states. Never bus/, zenoh_bridge/, web/,
ascii/.
"""
