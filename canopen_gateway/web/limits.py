"""Per-client request budgets of the web console: a token bucket per client address, so one
browser (or script) cannot keep the bus busy with SDO reads, and a refused request learns when
to try again (HTTP 429 with ``Retry-After``).

Runs on the event loop only (no lock). Bounded: at most ``max_clients`` buckets; when full, the
buckets that have refilled completely (clients that went quiet) are forgotten first.

Imports: the standard library only.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class ClientBudget:
    """``rate_per_s`` requests a second per client, ``burst`` at once."""

    def __init__(
        self,
        rate_per_s: float,
        burst: int,
        *,
        clock: Callable[[], float] = time.monotonic,
        max_clients: int = 1024,
    ):
        if rate_per_s <= 0 or burst < 1:
            raise ValueError("rate_per_s must be > 0 and burst >= 1")
        self.rate_per_s = rate_per_s
        self.burst = burst
        self.clock = clock
        self.max_clients = max_clients
        self._buckets: dict[str, tuple[float, float]] = {}  # client -> (tokens, at)
        self.refused = 0

    def take(self, client: str) -> float:
        """0.0 when the request may go ahead (one token taken); else the seconds to wait."""
        now = self.clock()
        tokens, at = self._buckets.get(client, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - at) * self.rate_per_s)
        if tokens >= 1.0:
            self._remember(client, tokens - 1.0, now)
            return 0.0
        self._remember(client, tokens, now)
        self.refused += 1
        return (1.0 - tokens) / self.rate_per_s

    def _remember(self, client: str, tokens: float, now: float) -> None:
        if client not in self._buckets and len(self._buckets) >= self.max_clients:
            full = [
                c
                for c, (t, at) in self._buckets.items()
                if t + (now - at) * self.rate_per_s >= self.burst
            ]
            for c in full or list(self._buckets)[: max(1, self.max_clients // 4)]:
                del self._buckets[c]
        self._buckets[client] = (tokens, now)
