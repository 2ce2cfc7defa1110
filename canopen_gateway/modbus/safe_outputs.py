"""Safe outputs: the value each RPDO output of a node falls back to when the controller that
writes it is gone (the Modbus output watchdog, ``modbus.watchdog_ms``).

A node's safe outputs are its profile's ``safe_value`` fields, overridden and extended by the
node's ``safe_outputs: {signal: value}`` in the config. Values are raw device values: what a
Modbus client writes to the signal's holding registers (a set point in device steps, a control
word as an integer). Only signals sent in one of the node's RPDOs may have one; an output
without a safe value keeps the last value sent.

``safe_outputs(lp, node)`` resolves one node (used by the Modbus server when the watchdog
trips); ``safe_output_problems(cfg)`` is the check of ``canopen-gateway check`` (key path and
what is allowed, as ``canopen_gateway.checks`` reports them).

Imports: config, errors, profiles, device.resolved, commands (``check_value``, pure). No I/O but reading profiles.
"""

from __future__ import annotations

from typing import Any

from canopen_gateway.commands import check_value
from canopen_gateway.config import Config, NodeConfig
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.errors import ValueOutOfRange
from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.profiles.schema import Signal


def rpdo_signals(lp: LoadedProfile, node: NodeConfig) -> list[Signal]:
    """The writable signals carried by the node's RPDO layout (its outputs)."""
    _, rpdos = lp.profile.layout(node.pdo_variant)
    mapped = {e.object for p in rpdos for e in p.mapping}
    return [
        s
        for s in lp.profile.signals
        if s.transport == "pdo" and s.access in ("rw", "wo") and s.object in mapped
    ]


def safe_outputs(lp: LoadedProfile, node: NodeConfig) -> dict[str, Any]:
    """Signal name -> checked raw safe value, profile values first, then the node's own."""
    outputs = {s.name: s for s in rpdo_signals(lp, node)}
    out: dict[str, Any] = {}
    for name, sig in outputs.items():
        if sig.safe_value is not None:
            out[name] = check_value(sig, sig.safe_value)
    for name, value in node.safe_outputs.items():
        out[name] = check_value(outputs[name], value)
    return out


def safe_output_problems(
    cfg: Config, nodes: dict[str, ResolvedNode]
) -> list[tuple[str, str]]:
    """Every safe value that names no RPDO output of its node or does not fit its type/range."""
    problems: list[tuple[str, str]] = []
    for i, n in enumerate(cfg.nodes):
        rn = nodes.get(n.name)
        if rn is None:
            continue  # its profile does not load: reported by the config loader
        lp = rn.lp
        outputs = {s.name: s for s in rpdo_signals(lp, n)}
        allowed = ", ".join(sorted(outputs)) or "none (the node has no RPDO output)"
        for name, sig in outputs.items():
            if sig.safe_value is not None:
                try:
                    check_value(sig, sig.safe_value)
                except ValueOutOfRange as exc:
                    problems.append(
                        (
                            f"nodes[{i}] (profile {lp.family}).signals.{name}.safe_value",
                            f"value {sig.safe_value!r} not allowed, expected {exc.allowed}",
                        )
                    )
        for name, value in n.safe_outputs.items():
            key = f"nodes[{i}].safe_outputs.{name}"
            target = outputs.get(name)
            if target is None:
                problems.append((key, f"not an RPDO output of node {n.name}; outputs: {allowed}"))
                continue
            try:
                check_value(target, value)
            except ValueOutOfRange as exc:
                problems.append((key, f"value {value!r} not allowed, expected {exc.allowed}"))
    return problems
