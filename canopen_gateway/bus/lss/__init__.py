"""LSS (CiA 305): the master's frames and the matching of the slaves' answers (``master``).

Imports: cia301. No I/O, no clock of its own.
"""
