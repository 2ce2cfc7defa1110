"""Environment overrides of the configuration: ``CANOPEN_GATEWAY__SECTION__KEY=value`` sets one
key (list items by index: ``CANOPEN_GATEWAY__NODES__0__NODE_ID=5``); values are parsed as YAML
scalars / flow lists, except the keys of ``ENV_TEXT_KEYS``, taken as written. A problem in a
value an override set is reported under the variable's name (``blame``), not the file's; so is
an unknown section or key the variable names, a list item that is not there and a value that is
not valid YAML (``VARIABLE: key.path: what``).

Imports: yaml, config.errors (key paths).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import yaml

from canopen_gateway.config.errors import key_path

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


def blame(loc: str, source: str, from_env: Mapping[str, str], *, unknown: bool = False) -> str:
    """Who wrote the value at ``loc``: the environment variable that set it (or a section
    above it), else the config file. ``unknown``: the problem is that the key at ``loc`` is
    not allowed; a variable that set a key below it wrote it on the way."""
    for path, var in from_env.items():
        if loc == path or loc.startswith((path + ".", path + "[")):
            return var
        if unknown and path.startswith((loc + ".", loc + "[")):
            return var
    return source


def _parse(value: str) -> Any:
    """An environment value as YAML (raises ``yaml.YAMLError``)."""
    return yaml.safe_load(value) if value != "" else ""


def _yaml_problem(exc: yaml.YAMLError) -> str:
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None)
    at = f" at character {mark.column + 1}" if mark is not None and mark.line == 0 else ""
    return (
        f"not valid YAML ({problem}{at}); values are read as YAML: a list as "
        "'[\"a\", \"b\"]', text with special characters in quotes"
    )


def apply_env_overrides(raw: dict[str, Any], environ: Mapping[str, str]) -> list[str]:
    """Apply ``CANOPEN_GATEWAY__A__B=v`` overrides in place; returns problems, each a line
    naming the variable and the key path."""
    problems = []
    for key, value in sorted(environ.items()):
        if not key.startswith(ENV_PREFIX):
            continue
        path = [p.lower() for p in key[len(ENV_PREFIX) :].split("__") if p]
        if not path:
            continue
        where = key_path(tuple(int(p) if p.isdigit() else p for p in path))
        if path[-1] in ENV_TEXT_KEYS:
            parsed: Any = value
        else:
            try:
                parsed = _parse(value)
            except yaml.YAMLError as exc:
                problems.append(f"{key}: {where}: {_yaml_problem(exc)}")
                continue
        node: Any = raw
        for i, part in enumerate(path):
            last = i == len(path) - 1
            if isinstance(node, list):
                if not part.isdigit() or int(part) >= len(node):
                    listed = key_path(tuple(int(p) if p.isdigit() else p for p in path[:i]))
                    problems.append(
                        f"{key}: {where}: no list item {part} ({listed} has {len(node)} "
                        + ("item)" if len(node) == 1 else "items)")
                    )
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
                above = key_path(tuple(int(p) if p.isdigit() else p for p in path[:i]))
                problems.append(f"{key}: {where}: {above} is not a section")
                break
    return problems
