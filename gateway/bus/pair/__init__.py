"""A hot-standby pair of gateways on one bus: which one is the bus's NMT master.

``flying_master.py`` is the role machine (CiA 302-2 NMT flying master, sans-I/O).

Imports: nothing.
"""
