"""The audit's values in engineering units: a write of signals reaches the command service as
raw device values; its audit record shows the engineering value (``scaling.engineering``, the
node's overrides applied) with the raw value beside it (``raw``). One signal: a value (a number
for a number); several: one of each per signal name.

Imports: errors, northbound.scaling, profiles.schema (types). The command service is seen
through ``Nodes``, a Protocol of the two look-ups it needs. Pure: no I/O.
"""

from __future__ import annotations

from typing import Any, Protocol

from canopen_gateway.errors import GatewayError
from canopen_gateway.northbound.scaling import Scaling, engineering
from canopen_gateway.profiles.schema import Signal


class Nodes(Protocol):
    """What is read of the command service: a node (its ``cfg.signals`` overrides) and a
    signal of it."""

    def node(self, name: str) -> Any: ...
    def signal(self, node: Any, name: str) -> Signal: ...


def engineering_record(rec: dict[str, Any], commands: Nodes) -> dict[str, Any]:
    """``rec`` with the engineering values of a ``write`` (other records as they are)."""
    raw = rec.get("value")
    if rec.get("op") != "write" or not isinstance(raw, dict) or not raw:
        return rec
    eng: dict[str, Any] = {}
    for name, value in raw.items():
        try:
            rt = commands.node(rec["node"])
            sig = commands.signal(rt, name)
            eng[name] = engineering(sig, value, Scaling.of(sig, rt.cfg.signals.get(name)))
        except (GatewayError, KeyError, TypeError, ValueError):
            eng[name] = value
    out = dict(rec)
    if len(raw) == 1:
        out["value"], out["raw"] = next(iter(eng.values())), next(iter(raw.values()))
    else:
        out["value"], out["raw"] = eng, raw
    return out
