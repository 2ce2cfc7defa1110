"""The Zenoh bridge's housekeeping on the event loop: held-back samples whose time has come
(``max_rate_hz``) and quality changes that no frame announces (stale by age), per node every
period (``HOUSEKEEPING_PERIOD_S``, shorter when a maximum rate needs it), and per node when its
health changes. Publication itself is the host's (``offer``, ``offer_pdo``, under each
publication's lock).

Imports: image; zenoh_bridge.plan for types only (its host is the ``HousekeepingHost``
Protocol, not the bridge). Never zenoh, modbus/ nor bus/.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from canopen_gateway.image import NodeImage

if TYPE_CHECKING:
    from canopen_gateway.image import ProcessImage
    from canopen_gateway.zenoh_bridge.plan import PdoPub, SignalPub

HOUSEKEEPING_PERIOD_S = 0.1


class HousekeepingHost(Protocol):
    """What the housekeeping needs of its host (``ZenohBridge``): the nodes, the planned
    publications by node, whether a session is open, the clock, and the two publications."""

    @property
    def image(self) -> ProcessImage: ...
    @property
    def pubs(self) -> Mapping[Any, SignalPub]: ...
    @property
    def by_node(self) -> Mapping[str, Sequence[SignalPub]]: ...
    @property
    def pdo_by_node(self) -> Mapping[str, Sequence[PdoPub]]: ...
    @property
    def session(self) -> object | None: ...
    @property
    def clock(self) -> Callable[[], float]: ...

    def offer(self, node: NodeImage, sp: SignalPub, now: float) -> None: ...
    def offer_pdo(self, node: NodeImage, pp: PdoPub, now: float, again: bool = False) -> None: ...


def refresh(bridge: HousekeepingHost, node: NodeImage, now: float) -> None:
    """Held-back samples whose time has come, and quality changes without a new frame."""
    for pp in bridge.pdo_by_node.get(node.name, ()):
        if pp.last_seq:
            bridge.offer_pdo(node, pp, now, again=True)
    for sp in bridge.by_node.get(node.name, ()):
        sv = node.signals[sp.sig.name]
        if not sv.seq:
            continue
        pol = sp.policy
        with sp.lock:  # the policy is the publishing thread's, under the signal's lock
            due = pol.take_due(now) or (
                pol.last_time_s is not None and node.quality(sv, now) != pol.last_quality
            )
        if due:
            bridge.offer(node, sp, now)


async def housekeeping_loop(bridge: HousekeepingHost) -> None:
    """Refresh every node each period while a session is open (event loop, until cancelled)."""
    period = HOUSEKEEPING_PERIOD_S
    rates = [sp.policy.min_interval_s for sp in bridge.pubs.values() if sp.policy.min_interval_s]
    if rates:
        period = max(0.01, min(period, min(rates) / 2))
    while True:
        await asyncio.sleep(period)
        if bridge.session is None:
            continue
        now = bridge.clock()
        for node in bridge.image.nodes.values():
            refresh(bridge, node, now)
