"""The resolved device model: what the gateway knows of each configured node before any frame.

``resolved`` resolves every node once when the config is loaded (its profile on its EDS, its
settings, its boot steps, the PDO codecs they leave in the device, its refresh plan and its
mapping reads) into a ``ResolvedNode`` that the master, Modbus, Zenoh, the web console, ``check``,
the simulator and the command-line tools take as a required argument. ``settings`` turns a node's
config into its ``NodeSettings`` (supervision, refresh, boot timeout), ``boot_steps`` builds the
ordered SDO writes of its boot configuration, ``values`` is the one encoding of a value of a CiA
301 type in an SDO transfer.

Below the bus in the layers: nothing here sends or receives a frame; it reads the device files.

Imports: nothing (its modules are imported by name).
"""
