"""SDO (CiA 301 7.2.4): the client transfer machine (``client``), the per-node channel that runs
one transfer at a time (``channel``) and the transfers clients await (``waiters``); the bytes of a
value in a transfer are ``canopen_gateway.device.values``.

Imports: cia301, errors, objref. No I/O.
"""
