"""Device features as hooks of the node's owner (``bus.node.node.Node``), as the simulator's
behaviours are hooks of ``SimNode``: the node calls every feature at its moments (boot-up,
values invalidated, configured and started, EMCY, a client's SDO done, time) and hands each
feature the SDO results of the purposes it owns. A feature returns what to do (``Output``s) and
says when it next needs time; it never does I/O.

A node has the features its profile and settings ask for (``Node.features``, built in
``Node.__init__``): ``refresh_on_start`` (``refresh``), ``referencing`` (``referencing``),
``verify_mapping`` (``verify_mapping``), ``rtr_poll_ms`` (``rtr_poll``), ``guarding_bit``
(``guarding_bit``), SYNC-driven TPDOs without a SYNC producer (``sync_wait``). The order is the
order they act in.

Imports: bus.node.events; bus.node.node, bus.sdo.channel and bus.sdo.client for types only. Never python-can, asyncio or
a northbound module.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gateway.bus.node.events import Output

if TYPE_CHECKING:
    from gateway.bus.node.node import Node
    from gateway.bus.sdo.channel import SdoJob
    from gateway.bus.sdo.client import SdoTransfer


class NodeFeature:
    """The hooks a feature may implement; each does nothing by default."""

    #: the SDO purposes this feature queues; their results come to ``sdo_done``
    purposes: tuple[str, ...] = ()

    def on_bootup(self, node: Node, now: float) -> list[Output]:
        """The device booted (its values and its configuration are gone)."""
        return []

    def on_invalidate(self, node: Node) -> None:
        """The node's values are no longer fresh (a boot-up or a loss)."""

    def on_lost(self, node: Node) -> list[Output]:
        """Supervision lost the node."""
        return []

    def on_configured(self, node: Node, now: float) -> list[Output]:
        """The node was configured and NMT start sent."""
        return []

    def on_adopted(self, node: Node, now: float) -> list[Output]:
        """A pair's take-over adopted the node as it runs (nothing was configured)."""
        return []

    def on_emcy(self, node: Node, now: float) -> bool:
        """An EMCY arrived; True when SDO work was queued (the node then starts it)."""
        return False

    def on_user_sdo(self, node: Node, job: SdoJob, now: float) -> list[Output]:
        """A client's SDO transfer finished."""
        return []

    def sdo_done(self, node: Node, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        """An SDO transfer of one of ``purposes`` finished."""
        return []

    def next_deadline(self) -> float | None:
        return None

    def tick(self, node: Node, now: float) -> list[Output]:
        """Time has passed (called at every tick of the node)."""
        return []
