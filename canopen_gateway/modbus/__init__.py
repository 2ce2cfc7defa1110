"""The Modbus TCP adapter: the server, the datastore that serves the process image and writes
through the command service (reads, writes, device identity), the register encoding, the
output watchdog and the safe outputs it writes, Modbus/TCP Security and the device
identification. The register map itself is shared (``northbound.regmap``).

Imports: commands, northbound, image, config, errors, states; of bus/ only the resolved nodes
(device.resolved). Never zenoh_bridge/, web/, ascii/.
"""
