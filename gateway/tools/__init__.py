"""Offline command-line tools that open their own connection to the bus (the gateway is not
running): the LSS session (``lss``).
"""
