"""The gateway's one rate-limited logger for recurring problems (per-frame errors, refused
requests): at most one line per kind and period, then a summary line with the count of what
was suppressed.

A *kind* is what the caller groups by: ``"unknown_cob_id"`` for every frame with an unexpected
COB-ID whatever its id (random traffic on thousands of ids still gives one line per period),
``("short_pdo", node)`` for one node's short PDOs. The first occurrence is logged at once with
its details; later ones within ``period_s`` are counted; ``flush`` (called periodically by its
owner) or the next occurrence after the period writes one summary line with the count.

Imports: the standard library only.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any


class RateLimitedLog:
    """Log a recurring problem at most once per ``period_s`` per kind, with a count."""

    def __init__(
        self,
        logger: logging.Logger,
        period_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.logger = logger
        self.period_s = period_s
        self.clock = clock
        self._last: dict[Any, float] = {}
        self._suppressed: dict[Any, tuple[int, str]] = {}  # kind -> (count, last message)
        self._lock = threading.Lock()  # called from the reader thread and the event loop
        self.lines = 0  # lines written (for tests and metrics)

    def warning(self, kind: Any, msg: str, *args: Any, extra: dict[str, Any] | None = None) -> None:
        self._log(logging.WARNING, kind, msg, args, extra)

    def info(self, kind: Any, msg: str, *args: Any, extra: dict[str, Any] | None = None) -> None:
        self._log(logging.INFO, kind, msg, args, extra)

    def log(self, level: int, kind: Any, msg: str, *args: Any) -> None:
        self._log(level, kind, msg, args)

    def _log(
        self, level: int, kind: Any, msg: str, args: tuple[Any, ...], extra: dict[str, Any] | None = None
    ) -> None:
        """``extra``: fields of the record (``{"node": name}``: the JSON log line's node)."""
        now = self.clock()
        with self._lock:
            last = self._last.get(kind)
            if last is not None and now - last < self.period_s:
                n, _ = self._suppressed.get(kind, (0, ""))
                self._suppressed[kind] = (n + 1, msg % args if args else msg)
                return
            self._last[kind] = now
            n, _ = self._suppressed.pop(kind, (0, ""))
            self.lines += 1
        if n:
            self.logger.log(
                level, msg + " (and %d more like it since the previous line)", *args, n,
                extra=extra,
            )
        else:
            self.logger.log(level, msg, *args, extra=extra)

    def flush(self) -> None:
        """Write the summary line of every kind whose period has ended with suppressed lines."""
        now = self.clock()
        due: list[tuple[Any, int, str]] = []
        with self._lock:
            for kind, (n, last_msg) in list(self._suppressed.items()):
                if now - self._last.get(kind, now) >= self.period_s:
                    del self._suppressed[kind]
                    self._last[kind] = now
                    due.append((kind, n, last_msg))
                    self.lines += 1
        for _kind, n, last_msg in due:
            self.logger.warning(
                "%d more like this in the last %.0f s, the last: %s", n, self.period_s, last_msg
            )
