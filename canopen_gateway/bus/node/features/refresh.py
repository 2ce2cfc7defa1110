"""Feature ``refresh_on_start``: right after NMT start, read the TPDOs that send only on change
(by RTR where the PDO allows it, else one SDO upload per mapped object; the plan is
``pdo.refresh``), so values are good without waiting for a change.

Imports: bus.node.features, bus.events, device.values, pdo.refresh;
bus.sdo.channel and bus.sdo.client for types only. No I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from canopen_gateway.bus.events import Output, Send, ValuesRead
from canopen_gateway.bus.node.features import NodeContext, NodeFeature
from canopen_gateway.device.values import decode_value
from canopen_gateway.pdo.refresh import Refresh

if TYPE_CHECKING:
    from canopen_gateway.bus.sdo.channel import SdoJob
    from canopen_gateway.bus.sdo.client import SdoTransfer


class RefreshOnStart(NodeFeature):
    purposes = ("refresh",)

    def __init__(self, plan: Sequence[Refresh]):
        self.plan = list(plan)

    def on_configured(self, node: NodeContext, now: float) -> list[Output]:
        out: list[Output] = []
        for r in self.plan:
            if r.how == "rtr":
                out.append(Send(r.codec.cob_id, b"", rtr=True, dlc=r.codec.length))
            else:
                for name, obj, type_ in r.objects:
                    node.sdo.queue(obj, None, "refresh", now, (name, obj, type_))
        return out

    def sdo_done(self, node: NodeContext, job: SdoJob, tr: SdoTransfer, now: float) -> list[Output]:
        if tr.result is None or node.health.fresh_since is None:
            return []
        name, _obj, type_ = job.arg
        try:
            value = decode_value(tr.result, type_)
        except Exception:  # noqa: BLE001 - a short answer: the value stays stale
            return []
        return [ValuesRead((name,), (value,), tr.started_s)]
