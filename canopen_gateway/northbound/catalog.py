"""The catalogue of a gateway (Zenoh ``<prefix>/catalog``, for cloud discovery): its CAN
networks (number, bus, nodes) and every node with its network and every signal with its type,
unit, scaling and Modbus addresses.

Pure: built from the config, the command service's read-only node infos and the register map
(nothing of the bus), at the moment it is asked for.

Imports: gateway (version), config, northbound.regmap, profiles.derived. Not the command
service (it imports the bus): its node infos are read through ``NodeInfos``.
"""

from __future__ import annotations

from typing import Any, Protocol

from canopen_gateway import __version__
from canopen_gateway.config import Config
from canopen_gateway.northbound.regmap import RegisterMap
from canopen_gateway.profiles.derived import text_rows_as_signals


class NodeInfos(Protocol):
    """What the catalogue reads of the command service: the node names and each node's
    read-only info (``commands.NodeInfo``: node id, profile)."""

    def names(self) -> list[str]: ...

    def node(self, name: str) -> Any: ...


def build_catalog(cfg: Config, commands: NodeInfos, rm: RegisterMap) -> dict[str, Any]:
    """Every network, node and signal (see the module docstring)."""
    addr: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for p in rm.points:
        if p.node and p.kind in ("signal", "bit"):
            addr.setdefault((p.node, p.name), []).append(
                {"unit_id": p.unit, "table": p.table, "address": p.address, "count": p.count}
                | ({"bit": p.bit} if p.bit is not None else {})
            )
    nodes = {}
    for name in commands.names():
        rt = commands.node(name)
        sigs = {}
        profile = rt.lp.profile
        for s in [*profile.signals, *text_rows_as_signals(profile)]:  # with the AP05 text rows
            sigs[s.name] = {
                "object": str(s.object),
                "type": s.type,
                "access": s.access,
                "transport": s.transport,
                "unit": s.unit,
                "scale": s.scale,
                "offset": s.offset,
                "description": s.description,
                "bits": {b.name: b.bit for b in s.bits},
                "modbus": addr.get((name, s.name), []),
            }
        nodes[name] = {
            "node_id": rt.node_id,
            "network": cfg.network_of(name),
            "profile": rt.lp.family,
            "title": rt.lp.profile.title,
            "signals": sigs,
        }
    networks = {
        view.network_names()[0]: {
            "number": number, "can": view.can.words(), "nodes": [n.name for n in view.nodes]
        }
        for number, view in enumerate(cfg.network_views(), start=1)
    }  # fmt: skip
    return {"gateway": cfg.gateway.name, "version": __version__, "networks": networks, "nodes": nodes}
