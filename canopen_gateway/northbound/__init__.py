"""What the northbound adapters share, pure and without I/O: the Modbus register map, the Zenoh
key scheme, engineering scaling and each node's health summary. Modbus, Zenoh, the web console
and the ASCII gateway each format these for their protocol; none imports another adapter.

Imports: config, profiles, resolved, image, states, objref. Never bus/ internals, pymodbus, zenoh,
or an adapter (modbus/, zenoh_bridge/, web/, ascii/).
"""
