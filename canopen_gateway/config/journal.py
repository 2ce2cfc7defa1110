"""The ``journal:`` section: where and how the gateway keeps its store and forward journal
(``canopen_gateway.journal``). Unset ``path``: no journal (events live in the advanced publishers'
caches only, ``seq`` starts at 1 at every start).

Whether the directory can be created and written is checked across the config
(``canopen_gateway.checks``, at ``check`` and at every start), not here: this module does no I/O.

Imports: pydantic. Nothing of bus/, modbus/, zenoh_bridge/, journal/.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class JournalSection(BaseModel):
    model_config = ConfigDict(extra="forbid")

    #: a directory (relative to the config file); None: no journal
    path: str | None = None
    #: the database is trimmed, oldest entries first, to stay within this size
    max_mb: float = Field(default=256, gt=0, le=1_000_000)
    #: resolution of the value history: the latest sample of each signal per window (0: events
    #: and the audit only)
    values_ms: int = Field(default=1000, ge=0, le=3_600_000)
    #: entries older than this go (oldest first)
    keep_days: float = Field(default=30, gt=0, le=36_500)
    #: ``normal``: a commit survives a crash of the gateway; ``full``: a power cut too (an fsync
    #: per commit)
    sync: Literal["normal", "full"] = "normal"
