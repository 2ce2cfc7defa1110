"""Device features as hooks of the node's owner (``bus.node.node.Node``), as the simulator's
features are hooks of ``SimNode``: the node calls every feature at its moments (boot-up,
values invalidated, configured and started, EMCY, a client's SDO done, time) and hands each
feature the SDO results of the purposes it owns. A feature returns what to do (``Output``s) and
says when it next needs time; it never does I/O.

A feature sees of its node only ``NodeContext``: its name, its health (the fields the feature
speaks of), its SDO channel (to queue the reads it owns) and its process image (the records
received). Everything else of the node is the node's own.

A node has the features its profile and settings ask for (``Node.features``, built by
``bus.node.parts.node_features``): ``refresh_on_start`` (``refresh``), ``referencing``
(``referencing``), ``verify_mapping`` (``verify_mapping``), ``rtr_poll_ms`` (``rtr_poll``),
``guarding_bit`` (``guarding_bit``), SYNC-driven TPDOs without a SYNC producer
(``sync_wait``). The order is the order they act in.

Imports: bus.events; image, bus.sdo.channel and bus.sdo.client for types only. Never
python-can, asyncio or a northbound module.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

from canopen_gateway.bus.events import Output

if TYPE_CHECKING:
    from canopen_gateway.bus.sdo.channel import SdoChannel, SdoJob
    from canopen_gateway.bus.sdo.client import SdoTransfer
    from canopen_gateway.image import NodeHealth, NodeImage


class NodeContext(Protocol):
    """What a feature sees of its node (``Node`` is one)."""

    @property
    def name(self) -> str: ...

    @property
    def health(self) -> NodeHealth: ...

    @property
    def sdo(self) -> SdoChannel: ...

    @property
    def image(self) -> NodeImage | None: ...


class NodeFeature:
    """The hooks a feature may implement; each does nothing by default."""

    #: the SDO purposes this feature queues; their results come to ``sdo_done``
    purposes: tuple[str, ...] = ()

    def on_bootup(self, node: NodeContext, now: float) -> list[Output]:
        """The device booted (its values and its configuration are gone)."""
        return []

    def on_invalidate(self, node: NodeContext) -> None:
        """The node's values are no longer fresh (a boot-up or a loss)."""

    def on_lost(self, node: NodeContext) -> list[Output]:
        """Supervision lost the node."""
        return []

    def on_configured(self, node: NodeContext, now: float) -> list[Output]:
        """The node was configured and NMT start sent."""
        return []

    def on_adopted(self, node: NodeContext, now: float) -> list[Output]:
        """A pair's take-over adopted the node as it runs (nothing was configured)."""
        return []

    def on_emcy(self, node: NodeContext, now: float) -> bool:
        """An EMCY arrived; True when SDO work was queued (the node then starts it)."""
        return False

    def on_user_sdo(self, node: NodeContext, job: SdoJob, now: float) -> list[Output]:
        """A client's SDO transfer finished."""
        return []

    def sdo_done(self, node: NodeContext, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        """An SDO transfer of one of ``purposes`` finished."""
        return []

    def next_deadline(self) -> float | None:
        return None

    def tick(self, node: NodeContext, now: float) -> list[Output]:
        """Time has passed (called at every tick of the node)."""
        return []
