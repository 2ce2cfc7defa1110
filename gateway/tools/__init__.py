"""Command-line tools that work on the bus or beside a running gateway (``scan``, ``monitor``,
and ``sdo``/``nmt`` through a running gateway). They drive parts of the gateway; nothing of the
gateway imports them."""
