"""The Zenoh key scheme (pure: no zenoh import): building keys, parsing query keys, and the
listing printed by ``canopen-gateway keys``.

Under a prefix (default ``canopen/<gateway name>``, ``zenoh.prefix`` in the config):

| key | kind | payload |
|---|---|---|
| ``<prefix>/<node>/value/<signal>`` | publication; get = latest (SDO read for SDO signals) | JSON value, unit, ts, quality, seq |
| ``<prefix>/<node>/state`` | event; get = current | JSON NMT state, alive, lifecycle, link |
| ``<prefix>/<node>/emcy`` | event | JSON code, register, text, manufacturer bytes |
| ``<prefix>/<node>/pdo/<cob-id hex>`` | publication (``raw_pdo``) | raw PDO bytes |
| ``<prefix>/<node>/tpdo/<n>`` | publication (``publish: pdo``) | JSON ts, seq, each signal's value, unit, quality |
| ``<prefix>/alive/<node>`` | liveliness token | present while the node is alive |
| ``<prefix>/alive/_gateway`` | liveliness token | present while the gateway runs |
| ``<prefix>/<node>/sdo/<index>/<sub>`` | query | get = SDO upload; with payload = download |
| ``<prefix>/<node>/snapshot`` | query | all current values and the state of the node |
| ``<prefix>/<node>/set/<signal>`` | query | write a signal (payload: JSON value) |
| ``<prefix>/<node>/set`` | query | write several signals of one node in one go |
| ``<prefix>/<node>/nmt`` | query | NMT command (payload: start, stop, preop, reset, reset-comm) |
| ``<prefix>/catalog`` | query | every node and signal: type, unit, scaling, Modbus address |

Imports: config, profiles, canopen.objref, device.resolved. Never zenoh, bus/, modbus/.
"""

from __future__ import annotations

import re
from collections.abc import Collection
from dataclasses import dataclass
from typing import Literal

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.profiles.derived import text_signals
from canopen_gateway.profiles.layout import tpdo_objects
from canopen_gateway.profiles.schema import Signal

#: the liveliness token of the gateway itself, ``<prefix>/alive/_gateway``
GATEWAY_TOKEN = "_gateway"

#: what a query key may ask for, after the node name
QUERY_FORMS = (
    "catalog",
    "<node>/snapshot",
    "<node>/state",
    "<node>/value/<signal>",
    "<node>/nmt",
    "<node>/set",
    "<node>/set/<signal>",
    "<node>/sdo/<index hex>/<sub hex>",
)

RequestKind = Literal["catalog", "snapshot", "state", "value", "nmt", "set", "set_many", "sdo"]


class BadKey(ValueError):
    """A query key that is not part of the scheme; the message says what was expected."""


@dataclass(frozen=True)
class KeyInfo:
    key: str
    kind: str  # value | event | liveliness | query | raw
    description: str
    node: str = ""


@dataclass(frozen=True)
class Request:
    """What a query key asks for."""

    kind: RequestKind
    node: str = ""
    signal: str = ""
    obj: ObjRef | None = None


# --------------------------------------------------------------------------- building keys


def prefix_of(cfg: Config) -> str:
    return cfg.zenoh.key_prefix(cfg.gateway.name).rstrip("/")


def value_key(prefix: str, node: str, signal: str) -> str:
    return f"{prefix}/{node}/value/{signal}"


def audit_key(prefix: str) -> str:
    """The journal's audit of writes, answered by ``get <prefix>/audit?_time=[...]``."""
    return f"{prefix}/audit"


def state_key(prefix: str, node: str) -> str:
    return f"{prefix}/{node}/state"


def emcy_key(prefix: str, node: str) -> str:
    return f"{prefix}/{node}/emcy"


def pdo_key(prefix: str, node: str, cob_id: int) -> str:
    return f"{prefix}/{node}/pdo/{cob_id:03x}"


def tpdo_key(prefix: str, node: str, number: int) -> str:
    """One sample per received PDO with all its signals (``zenoh.publish: pdo``)."""
    return f"{prefix}/{node}/tpdo/{number}"


def alive_key(prefix: str, node: str) -> str:
    return f"{prefix}/alive/{node}"


def catalog_key(prefix: str) -> str:
    return f"{prefix}/catalog"


def snapshot_key(prefix: str, node: str) -> str:
    return f"{prefix}/{node}/snapshot"


def nmt_key(prefix: str, node: str) -> str:
    return f"{prefix}/{node}/nmt"


def set_key(prefix: str, node: str, signal: str | None = None) -> str:
    return f"{prefix}/{node}/set" + (f"/{signal}" if signal else "")


def sdo_key(prefix: str, node: str, obj: ObjRef) -> str:
    return f"{prefix}/{node}/sdo/{obj.index:04x}/{obj.sub:02x}"


def is_published(sig: Signal, inputs: Collection[ObjRef] = frozenset()) -> bool:
    """Signals decoded from a TPDO get a value key: the inputs, and an output whose object a
    TPDO carries too (``inputs``: the node's TPDO objects, ``profiles.layout.tpdo_objects``).
    RPDO-only outputs and SDO objects do not."""
    return sig.transport == "pdo" and (sig.access == "ro" or sig.object in inputs)


def is_writable(sig: Signal) -> bool:
    return sig.access in ("rw", "wo")


# --------------------------------------------------------------------------- parsing queries


def _hex(text: str, what: str, limit: int) -> int:
    t = text.lower().removeprefix("0x").removesuffix("h")
    if not t or not re.fullmatch(r"[0-9a-f]+", t):
        raise BadKey(f"{what} {text!r} is not hexadecimal (e.g. 6004 or 0x6004)")
    v = int(t, 16)
    if v > limit:
        raise BadKey(f"{what} {text!r} is above 0x{limit:X}")
    return v


def has_wildcard(key: str) -> bool:
    return "*" in key or "$" in key


def parse_key(prefix: str, key: str) -> Request:
    """The request a concrete query key stands for; ``BadKey`` says what was expected."""
    expected = "expected " + " or ".join(f"{prefix}/{f}" for f in QUERY_FORMS)
    if not key.startswith(prefix + "/"):
        raise BadKey(f"key {key} is not under {prefix}; {expected}")
    parts = key[len(prefix) + 1 :].split("/")
    if parts == ["catalog"]:
        return Request("catalog")
    if parts[0] == "alive":
        raise BadKey(f"{key} is a liveliness token: use a liveliness get or subscriber")
    node, rest = parts[0], parts[1:]
    if rest == ["snapshot"]:
        return Request("snapshot", node)
    if rest == ["state"]:
        return Request("state", node)
    if rest == ["nmt"]:
        return Request("nmt", node)
    if rest == ["set"]:
        return Request("set_many", node)
    if len(rest) == 2 and rest[0] == "set":
        return Request("set", node, signal=rest[1])
    if len(rest) == 2 and rest[0] == "value":
        return Request("value", node, signal=rest[1])
    if rest and rest[0] == "sdo":
        if len(rest) != 3:
            raise BadKey(f"SDO key {key}: expected {prefix}/{node}/sdo/<index hex>/<sub hex>")
        obj = ObjRef(_hex(rest[1], "index", 0xFFFF), _hex(rest[2], "sub-index", 0xFF))
        return Request("sdo", node, obj=obj)
    if rest == ["emcy"] or rest[:1] in (["pdo"], ["tpdo"]):
        raise BadKey(f"{key} is a publication: subscribe to it")
    raise BadKey(f"unknown key {key}; {expected}")


# --------------------------------------------------------------------------- the listing


def short_text(text: str, limit: int = 56) -> str:
    """The first clause of a profile description on one line, at most ``limit`` characters."""
    t = " ".join(text.split())
    for stop in (". ", "; ", " = ", ": "):
        i = t.find(stop)
        if 0 < i:
            t = t[:i]
    t = t.rstrip(".")
    return t if len(t) <= limit else t[: limit - 3].rstrip() + "..."


def _signal_text(sig: Signal, unit: str) -> str:
    kind = sig.type_name + (f" [{unit}]" if unit else "")
    desc = short_text(sig.description) if sig.description else ""
    return f"{kind}  {desc}".rstrip()


def all_keys(cfg: Config, nodes: dict[str, ResolvedNode]) -> list[KeyInfo]:
    p = prefix_of(cfg)
    out = [
        KeyInfo(alive_key(p, GATEWAY_TOKEN), "liveliness", "the gateway is running"),
        KeyInfo(catalog_key(p), "query", "every node and signal: type, unit, scaling, Modbus"),
    ]
    for n in cfg.nodes:
        lp = nodes[n.name].lp
        name = n.name

        def add(key: str, kind: str, text: str, _name: str = name) -> None:
            out.append(KeyInfo(key, kind, text, _name))

        add(alive_key(p, name), "liveliness", "values usable: operational, supervision and process-data link OK")
        add(state_key(p, name), "event", "NMT state, supervision, link, errors (get: current)")
        add(emcy_key(p, name), "event", "EMCY: code, register, text")
        inputs = tpdo_objects(lp.profile, n.pdo_variant)
        for s in lp.profile.signals:
            ov = n.signals.get(s.name)
            if not is_published(s, inputs) or (ov is not None and ov.publish == "off"):
                continue
            unit = ov.unit if ov is not None and ov.unit is not None else s.unit
            add(value_key(p, name, s.name), "value", _signal_text(s, unit))
        for s in lp.profile.signals:
            if is_writable(s):
                via = "RPDO" if s.transport == "pdo" else f"SDO {s.object}"
                add(set_key(p, name, s.name), "query", f"write {s.type} ({via})")
        for t in text_signals(lp.profile):  # AP05 alpha-numeric rows (profiles/derived.py)
            add(set_key(p, name, t.name), "query", f"write string of up to {t.length} characters (RPDO, text of row {t.row})")
        add(f"{p}/{name}/value/<sdo signal>", "query", "SDO read of a configuration signal")
        add(set_key(p, name), "query", 'write several signals: {"signal": value, ...}')
        add(f"{p}/{name}/sdo/<index>/<sub>", "query", "SDO upload (get) / download (payload)")
        add(snapshot_key(p, name), "query", "all current values and the state")
        add(nmt_key(p, name), "query", "NMT: start, stop, preop, reset, reset-comm")
        if cfg.zenoh.publish == "pdo":
            add(f"{p}/{name}/tpdo/<n>", "value", "one sample per received TPDO, all its signals")
        if cfg.zenoh.raw_pdo:
            add(f"{p}/{name}/pdo/<cob-id hex>", "raw", "raw PDO bytes, received and sent")
    return out


def render_keys(cfg: Config, nodes: dict[str, ResolvedNode]) -> str:
    """The listing of ``canopen-gateway keys``: one line per key, grouped by node."""
    keys = all_keys(cfg, nodes)
    width = max((len(k.key) for k in keys), default=10)
    lines = [f"# prefix {prefix_of(cfg)}  (payloads: docs/zenoh.md)"]
    current = None
    configured = {n.name: n for n in cfg.nodes}
    for k in keys:
        if k.node != current:
            current = k.node
            n = configured.get(k.node)
            if n is not None:
                lines.append("")
                on = f", network {cfg.network_of(n.name)}" if cfg.networks is not None else ""
                lines.append(f"# node {n.name}: {n.device}, node id {n.node_id}{on}")
        lines.append(f"{k.key:<{width}}  {k.kind:<10}  {k.description}")
    return "\n".join(lines) + "\n"
