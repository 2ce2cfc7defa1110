"""Command-line tools: those that work on the bus or beside a running gateway (``scan``,
``monitor``, and ``sdo``/``nmt`` through a running gateway) and the offline ones that open their
own connection to the bus while the gateway is not running (the LSS session, ``lss``). They drive
parts of the gateway; nothing of the gateway imports them.

Imports: nothing (its modules are imported by name).
"""
