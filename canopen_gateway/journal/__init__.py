"""Store and forward: the gateway's on-disk journal of what it heard and published (state and
EMCY events, values at ``journal.values_ms`` resolution) and of every write it was asked for
(the audit), read back for history by time range.

- ``store``: the journal (its queue, its writer thread, its bounds, its status);
- ``db``: the SQLite database (schema, commit, upkeep, reading in time order);
- ``files``: the files around it (the OS lock, damage, set-aside files, the marks' copy);
- ``clock``: nanosecond times, NTP64, and the hybrid clock of the gateway's stamps;
- ``timerange``: the ``_time`` selector grammar of Zenoh storages, parsed into bounds.

Imports: store, db, files, clock, timerange (its own modules). Never an adapter (modbus/,
zenoh_bridge/, web/, ascii/), nor bus/ or commands/: they hand it entries.
"""

from canopen_gateway.journal.clock import (
    HybridClock,
    ns_of_ntp64,
    ntp64_of_ns,
    ntp64_of_time,
    time_of_ntp64,
)
from canopen_gateway.journal.db import Row
from canopen_gateway.journal.files import FILE_NAME, FileLock, JournalInUse, path_problem
from canopen_gateway.journal.store import Entry, Journal
from canopen_gateway.journal.timerange import (
    TimeRange,
    TimeRangeError,
    parse_instant_ns,
    parse_time_range,
)

__all__ = [
    "FILE_NAME",
    "Entry",
    "FileLock",
    "HybridClock",
    "Journal",
    "JournalInUse",
    "Row",
    "TimeRange",
    "TimeRangeError",
    "ns_of_ntp64",
    "ntp64_of_ns",
    "ntp64_of_time",
    "parse_instant_ns",
    "parse_time_range",
    "path_problem",
    "time_of_ntp64",
]
