"""Report-by-exception policy of one published signal (pure: no zenoh, no clock of its own).

Decides, for each new sample of a signal, whether it is published now, later, or not at all:

=========  ===============================================================  =====================
mode       a new sample is published when                                   otherwise
=========  ===============================================================  =====================
change     it differs from the last published one by at least the           dropped (nothing
           deadband (engineering units), or its quality changed             new to say)
every      always                                                           -
=========  ===============================================================  =====================

With a maximum rate, a sample that would be published sooner than ``1 / max_rate_hz`` after
the previous publication is held back (``pending``); ``due(now)`` says when the latest value
must go out, so the last change is never lost when the signal then stands still. A quality
change (good -> stale on a lost node) is published even when the value did not change.

The caller holds the lock of the signal around ``offer`` / ``published`` (the reader thread
and the event loop both publish). Times are seconds of a monotonic clock passed in.

Imports: nothing of the gateway.
"""

from __future__ import annotations

from typing import Any, Literal

PublishMode = Literal["change", "every"]


class ReportPolicy:
    __slots__ = ("mode", "deadband", "scale", "min_interval_s", "last_value", "last_quality",
                 "last_time_s", "pending", "published_count")  # fmt: skip

    def __init__(
        self,
        mode: PublishMode = "change",
        deadband: float = 0.0,
        scale: float = 1.0,
        max_rate_hz: float | None = None,
    ):
        if mode not in ("change", "every"):
            raise ValueError(f"mode must be change or every, not {mode!r}")
        self.mode = mode
        self.deadband = deadband
        self.scale = abs(scale) or 1.0
        self.min_interval_s = 1.0 / max_rate_hz if max_rate_hz else 0.0
        self.last_value: Any = None
        self.last_quality: Any = None
        self.last_time_s: float | None = None
        self.pending = False
        self.published_count = 0

    def changed(self, value: Any, quality: Any) -> bool:
        """Does this sample say something the last published one did not?"""
        if self.last_time_s is None or quality != self.last_quality:
            return True
        last = self.last_value
        if value == last:
            return False
        if (
            self.deadband
            and isinstance(value, (int, float))
            and isinstance(last, (int, float))
            and abs(value - last) * self.scale < self.deadband
        ):
            return False
        return True

    def offer(self, value: Any, quality: Any, now_s: float) -> bool:
        """A new sample: True = publish it now (then call ``published``)."""
        if self.mode == "change" and not self.changed(value, quality):
            return False
        if (
            self.min_interval_s
            and self.last_time_s is not None
            and now_s - self.last_time_s < self.min_interval_s
        ):
            self.pending = True
            return False
        return True

    def published(self, value: Any, quality: Any, now_s: float) -> None:
        self.last_value = value
        self.last_quality = quality
        self.last_time_s = now_s
        self.pending = False
        self.published_count += 1

    def due(self, now_s: float) -> bool:
        """A held-back sample whose time has come."""
        return (
            self.pending
            and self.last_time_s is not None
            and now_s - self.last_time_s >= self.min_interval_s
        )

    def take_due(self, now_s: float) -> bool:
        """``due`` and forget the hold: the caller then offers the current value again."""
        if not self.due(now_s):
            return False
        self.pending = False
        return True
