"""Store and forward: the gateway's on-disk journal of what it published (state and EMCY
events, values at ``journal.values_ms`` resolution) and of every write it was asked for (the
audit), read back for history by time range.

- ``store``: the SQLite database, its writer thread, its bounds and its readers;
- ``timerange``: the ``_time`` selector grammar of Zenoh storages, parsed into NTP64 bounds.

Imports: store, timerange (its own modules). Never an adapter (modbus/, zenoh_bridge/, web/,
ascii/), nor bus/ or commands/: they hand it entries.
"""

from gateway.journal.store import (
    FILE_NAME,
    Entry,
    Journal,
    Row,
    ntp64_of_time,
    path_problem,
    time_of_ntp64,
)
from gateway.journal.timerange import TimeRange, TimeRangeError, parse_time_range

__all__ = [
    "FILE_NAME",
    "Entry",
    "Journal",
    "Row",
    "TimeRange",
    "TimeRangeError",
    "ntp64_of_time",
    "parse_time_range",
    "path_problem",
    "time_of_ntp64",
]
