"""A hot-standby pair of gateways on one bus: which one is the bus's NMT master.

``protocol.py`` its frames, roles and events; ``flying_master.py`` the role machine (CiA 302-2
NMT flying master, sans-I/O); ``member.py`` its timer, own heartbeat and link reports on the
event loop; ``side.py`` the master's pair-only part and the null member outside a pair.

Imports: nothing.
"""
