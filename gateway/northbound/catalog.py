"""The catalogue: every node and signal of a gateway with its type, unit, scaling and Modbus
address, for cloud discovery (Zenoh ``<prefix>/catalog``). Pure: read from the command
service's node views (nothing of the bus) and the register map, at the moment it is asked for.

Imports: gateway (version), northbound.regmap, profiles.derived (the AP05 text rows as
signals); the command service's node views are seen as a Protocol (``NodeViews``).
"""

from __future__ import annotations

from typing import Any, Protocol

from gateway import __version__
from gateway.northbound.regmap import RegisterMap
from gateway.profiles.derived import text_rows_as_signals


class NodeViews(Protocol):
    """What the catalogue reads of the command service: its nodes' read-only views."""

    def names(self) -> list[str]: ...
    def node(self, name: str) -> Any: ...


def build_catalog(gateway_name: str, commands: NodeViews, regmap: RegisterMap) -> dict[str, Any]:
    """``{"gateway", "version", "nodes": {name: {"node_id", "profile", "title", "signals"}}}``."""
    addr: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for p in regmap.points:
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
            "profile": rt.lp.family,
            "title": rt.lp.profile.title,
            "signals": sigs,
        }
    return {"gateway": gateway_name, "version": __version__, "nodes": nodes}
