"""Environment overrides of the configuration: ``CANOPEN_GATEWAY__SECTION__KEY=value`` sets one
key (list items by index: ``CANOPEN_GATEWAY__NODES__0__NODE_ID=5``); values are parsed as YAML
scalars / flow lists, except the keys of ``ENV_TEXT_KEYS``, taken as written. A problem in a
value an override set is reported under the variable's name (``blame``), not the file's.

Imports: yaml, config.errors (key paths).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import yaml

from gateway.config.errors import key_path

ENV_PREFIX = "CANOPEN_GATEWAY__"
#: keys whose environment values are taken as written, never as YAML numbers (a token of
#: digits, "0123...", must keep its leading zero)
ENV_TEXT_KEYS = frozenset({"token", "password"})


def env_keys(environ: Mapping[str, str]) -> dict[str, str]:
    """Key path (``modbus.port``, ``nodes[0].node_id``) -> the environment variable that sets it."""
    out = {}
    for key in environ:
        if not key.startswith(ENV_PREFIX):
            continue
        path = [p.lower() for p in key[len(ENV_PREFIX) :].split("__") if p]
        if path:
            out[key_path(tuple(int(p) if p.isdigit() else p for p in path))] = key
    return out


def blame(loc: str, source: str, from_env: Mapping[str, str]) -> str:
    """Who wrote the value at ``loc``: the environment variable that set it (or a section
    above it), else the config file."""
    for path, var in from_env.items():
        if loc == path or loc.startswith((path + ".", path + "[")):
            return var
    return source


def apply_env_overrides(raw: dict[str, Any], environ: Mapping[str, str]) -> list[str]:
    """Apply ``CANOPEN_GATEWAY__A__B=v`` overrides in place; returns problems."""
    problems = []
    for key, value in sorted(environ.items()):
        if not key.startswith(ENV_PREFIX):
            continue
        path = [p.lower() for p in key[len(ENV_PREFIX) :].split("__") if p]
        if not path:
            continue
        try:
            parsed = yaml.safe_load(value) if value != "" else ""
        except yaml.YAMLError:
            parsed = value
        if path[-1] in ENV_TEXT_KEYS:
            parsed = value
        node: Any = raw
        for i, part in enumerate(path):
            last = i == len(path) - 1
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    problems.append(f"environment {key}: no list item {part!r}")
                    break
                if last:
                    node[int(part)] = parsed
                else:
                    node = node[int(part)]
            elif isinstance(node, dict):
                if last:
                    node[part] = parsed
                else:
                    node = node.setdefault(part, {})
            else:
                problems.append(f"environment {key}: {'.'.join(path[:i])} is not a section")
                break
    return problems
