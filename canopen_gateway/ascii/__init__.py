"""CiA 309-3 ASCII gateway: the command language of CANopenNode's canopend and Lely's coctl on
TCP, as a northbound adapter beside Modbus and Zenoh.

``protocol`` is the language without I/O (lines in, requests and answers out); ``server`` is the
asyncio TCP server that runs it against the command service.

Imports: nothing (its modules are imported by name: ascii.protocol, ascii.server).
"""
