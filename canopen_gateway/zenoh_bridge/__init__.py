"""The Zenoh adapter: value and event publications, queries (get, set, SDO, NMT), liveliness
tokens and the JSON payloads. The key scheme itself is shared (``northbound.keys``).

Imports: zenoh, commands, northbound, image, config, errors. Never bus/, modbus/, web/, ascii/.
"""
