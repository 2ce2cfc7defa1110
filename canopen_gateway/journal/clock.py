"""Time as the journal and the Zenoh bridge stamp what they keep and publish: nanoseconds since
1970 (UTC), and Zenoh's NTP64 (seconds since 1970 << 32 | fraction) converted to the nanosecond
exactly as Zenoh converts it (``ntp64_of_ns`` / ``ns_of_ntp64``: a time made of nanoseconds
goes through ``zenoh.Timestamp`` and back unchanged, so a bound of ``_time`` written to the
nanosecond finds the sample stamped with it).

``HybridClock`` makes the stamps: the wall clock (``time.time_ns``), but never less than 1 ns
after the last stamp made or seen (``observe``). So the stamps of one gateway never go back:
not when the wall clock is stepped back, not across a restart (the journal seeds the clock with
the newest time it holds), not across a take-over in a hot-standby pair (the standby observes
every timestamp it hears and journals). While the wall clock is behind the last stamp, stamps
advance 1 ns at a time until it catches up (as Zenoh's own hybrid logical clock does).

Imports: the standard library only.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

NANOS = 1_000_000_000
FRACTION = 1 << 32
NTP64_MAX = (1 << 64) - 1


def ntp64_of_ns(ns: int) -> int:
    """Nanoseconds since 1970 as NTP64 (Zenoh's ``NTP64(secs, nanos)``: the fraction floored)."""
    secs, sub = divmod(ns, NANOS)
    return (secs << 32) | ((sub << 32) // NANOS)


def ns_of_ntp64(n: int) -> int:
    """NTP64 as nanoseconds since 1970, rounded as Zenoh rounds (``NTP64.subsec_nanos``)."""
    return (n >> 32) * NANOS + (((n & 0xFFFFFFFF) * NANOS + (1 << 31)) >> 32)


def ntp64_of_time(t: float) -> int:
    """Seconds since 1970 as NTP64 (to the nanosecond)."""
    return ntp64_of_ns(round(t * NANOS))


def time_of_ntp64(n: int) -> float:
    return ns_of_ntp64(n) / NANOS


class HybridClock:
    """Strictly increasing stamps in nanoseconds since 1970 (see the module docstring). Any
    thread; ``now_ns`` injectable."""

    def __init__(self, now_ns: Callable[[], int] = time.time_ns) -> None:
        self.now_ns = now_ns
        self._lock = threading.Lock()
        self._last = 0

    def stamp(self) -> int:
        """A new stamp: the wall clock, or 1 ns after the last stamp when that is later."""
        now = self.now_ns()
        with self._lock:
            self._last = now if now > self._last else self._last + 1
            return self._last

    def observe(self, ns: int) -> None:
        """A time made elsewhere (a stamp journaled before, a sample heard): the next stamps
        come after it."""
        with self._lock:
            if ns > self._last:
                self._last = ns

    @property
    def last_ns(self) -> int:
        return self._last

    def ahead_s(self) -> float:
        """How far the last stamp is ahead of the wall clock (0 when it is not)."""
        return max(0.0, (self._last - self.now_ns()) / NANOS)
