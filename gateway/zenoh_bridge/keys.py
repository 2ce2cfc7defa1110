"""The Zenoh key scheme (pure: no zenoh import), also printed by ``canopen-gateway keys``.

Under a prefix (default ``canopen/<gateway name>``):

| key | kind | payload |
|---|---|---|
| ``<prefix>/<node>/value/<signal>`` | publication | JSON value, unit, ts, quality, seq |
| ``<prefix>/<node>/state`` | publication (event) | JSON NMT state, alive, lifecycle, link |
| ``<prefix>/<node>/emcy`` | publication (event) | JSON code, register, text, manufacturer |
| ``<prefix>/<node>/pdo/<cob-id hex>`` | publication (optional) | raw PDO bytes |
| ``<prefix>/alive/<node>`` | liveliness token | present while the node is alive |
| ``<prefix>/alive/_gateway`` | liveliness token | present while the gateway runs |
| ``<prefix>/<node>/sdo/<index>/<sub>`` | query | get = SDO upload; with payload = download |
| ``<prefix>/<node>/snapshot`` | query | all current values of the node |
| ``<prefix>/<node>/set/<signal>`` | query | write a signal (payload: JSON value) |
| ``<prefix>/<node>/set`` | query | write several signals of one node in one go |
| ``<prefix>/<node>/nmt`` | query | NMT command (payload: start, stop, preop, reset, reset-comm) |
| ``<prefix>/catalog`` | query | every node and signal: type, unit, scaling, Modbus address |

Imports: config, profiles. Never zenoh, bus/, modbus/.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway.config import Config
from gateway.profiles import load_profile

GATEWAY_TOKEN = "_gateway"


@dataclass(frozen=True)
class KeyInfo:
    key: str
    kind: str
    description: str


def prefix_of(cfg: Config) -> str:
    return cfg.zenoh.key_prefix(cfg.gateway.name).rstrip("/")


def value_key(prefix: str, node: str, signal: str) -> str:
    return f"{prefix}/{node}/value/{signal}"


def state_key(prefix: str, node: str) -> str:
    return f"{prefix}/{node}/state"


def emcy_key(prefix: str, node: str) -> str:
    return f"{prefix}/{node}/emcy"


def pdo_key(prefix: str, node: str, cob_id: int) -> str:
    return f"{prefix}/{node}/pdo/{cob_id:03x}"


def alive_key(prefix: str, node: str) -> str:
    return f"{prefix}/alive/{node}"


def all_keys(cfg: Config) -> list[KeyInfo]:
    p = prefix_of(cfg)
    out = [
        KeyInfo(alive_key(p, GATEWAY_TOKEN), "liveliness", "the gateway is running"),
        KeyInfo(f"{p}/catalog", "query", "catalogue of all nodes and signals"),
    ]
    for n in cfg.nodes:
        lp = load_profile(n.profile, cfg.base_dir)
        out.append(KeyInfo(alive_key(p, n.name), "liveliness", f"node {n.name} is alive"))
        out.append(KeyInfo(state_key(p, n.name), "event", "NMT state / supervision changes"))
        out.append(KeyInfo(emcy_key(p, n.name), "event", "EMCY messages"))
        for s in lp.profile.signals:
            if s.transport == "pdo":
                out.append(
                    KeyInfo(
                        value_key(p, n.name, s.name),
                        "value",
                        f"{s.description or s.name} [{s.unit}]".replace(" []", ""),
                    )
                )
        for s in lp.profile.signals:
            if s.access in ("rw", "wo"):
                out.append(KeyInfo(f"{p}/{n.name}/set/{s.name}", "query", f"write {s.name}"))
        out.append(KeyInfo(f"{p}/{n.name}/sdo/<index>/<sub>", "query", "SDO upload / download"))
        out.append(KeyInfo(f"{p}/{n.name}/snapshot", "query", "all current values"))
        out.append(KeyInfo(f"{p}/{n.name}/set", "query", "write several signals at once"))
        out.append(KeyInfo(f"{p}/{n.name}/nmt", "query", "NMT command"))
        if cfg.zenoh.raw_pdo:
            out.append(KeyInfo(f"{p}/{n.name}/pdo/<cob-id>", "value", "raw PDO bytes"))
    return out
