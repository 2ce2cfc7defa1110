"""The basics of running, that every layer's threads and loops use: threads.py (named threads
whose death is logged), ratelimit.py (log lines that never flood), turns.py (the event loop's
turns: the PLC first), startup.py (a start-up failure as one line: the setting, its value, the
reason). Standard library only.

Imports: nothing of the gateway (each module names its own).
"""
