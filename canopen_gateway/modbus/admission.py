"""Who may hold a Modbus connection: the caps on connections in total and per client address
(``modbus.max_connections``, ``modbus.max_connections_per_client``), and which connection
gives way when the total is reached (pure: no sockets, no clock).

Reaching the port is not permission to take the PLC's place. The decision is made for each
accepted socket before anything is read from it:

=====================================================  ==================================
the new connection's client                             decision
=====================================================  ==================================
holds ``max_connections_per_client`` already            ``per_client``: closed at once
the total is reached, the client is trusted and a       ``evict``: the longest-idle
connection of an untrusted client is open               untrusted connection is closed,
                                                        the new one served
the total is reached otherwise                          ``total``: closed at once
else                                                    ``admit``
=====================================================  ==================================

Trusted clients are those in ``modbus.allowed_networks`` (the ones that may write: the PLC),
so a flood from addresses outside them never keeps the PLC out, and a flood from one address
inside them holds at most ``max_connections_per_client`` connections. Refusals are counted by
reason (``modbus_connections_closed_total{reason}``).

Imports: the standard library only.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

Decision = Literal["admit", "evict", "per_client", "total"]


class Admission:
    """The open connections per client address and the caps on them."""

    def __init__(self, max_total: int, max_per_client: int, trusted: Callable[[str], bool]):
        self.max_total = max_total
        self.max_per_client = max_per_client
        self.trusted = trusted
        self.per_client: dict[str, int] = {}
        self.total = 0
        self.untrusted = 0  # open connections of clients outside the trusted networks
        #: connections closed by this gateway, by reason (per_client, total, evicted, idle)
        self.closed_by_reason: dict[str, int] = {}

    def decide(self, address: str) -> Decision:
        """What to do with a new connection from ``address`` (nothing is counted yet)."""
        if self.per_client.get(address, 0) >= self.max_per_client:
            return "per_client"
        if self.total < self.max_total:
            return "admit"
        if self.untrusted and self.trusted(address):
            return "evict"
        return "total"

    def opened(self, address: str) -> None:
        self.per_client[address] = self.per_client.get(address, 0) + 1
        self.total += 1
        if not self.trusted(address):
            self.untrusted += 1

    def closed(self, address: str) -> None:
        n = self.per_client.get(address, 0) - 1
        if n > 0:
            self.per_client[address] = n
        else:
            self.per_client.pop(address, None)
        self.total -= 1
        if not self.trusted(address):
            self.untrusted -= 1

    def counts(self) -> tuple[int, dict[str, int]]:
        """(connections open, closed by the gateway by reason) for the metrics."""
        return self.total, dict(self.closed_by_reason)

    def count(self, reason: str) -> int:
        """One connection closed by the gateway for ``reason``; the count so far."""
        n = self.closed_by_reason.get(reason, 0) + 1
        self.closed_by_reason[reason] = n
        return n
