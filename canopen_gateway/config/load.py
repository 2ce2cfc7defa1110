"""Loading the configuration: read the YAML file, apply the environment overrides, validate
the sections (``config.model``) and check what one file can say about itself beyond its
sections: duplicate node ids, names and Modbus unit ids, names that refer to nodes. A caller that
resolves the nodes (``canopen_gateway.device.resolved``: each node's profile or EDS, its signal overrides,
PDO variant and ``verify_mapping``) passes ``resolve``, whose problems join the file's. Every problem is
reported as one line naming the file (or the environment variable), the key path and what is
allowed; all problems of a file are collected before ``ConfigError`` is raised.

The checks across the config, the profiles/EDS and the compiled register map
(``canopen-gateway check``) live in ``canopen_gateway.checks``, which imports this package.

Imports: pydantic, yaml, config.model, config.errors,
config.env, config.networks (the networks: form's problems, every node entry).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import ValidationError

from canopen_gateway.config.env import apply_env_overrides, blame, env_keys
from canopen_gateway.config.errors import ConfigError, describe, key_path, nearest_key
from canopen_gateway.config.model import Config
from canopen_gateway.config.networks import network_problems, node_entries

#: what a config's nodes add to its problems once its sections validate: (key path, why) each
Resolve = Callable[[Config], list[tuple[str, str]]]


def _semantic_problems(raw: dict[str, Any], base_dir: Path) -> list[tuple[str, str]]:
    """Checks across entries that pydantic cannot see, run on the raw data: a node id twice on
    one network, a node name twice in the gateway, two nodes on one Modbus unit (and the
    ``networks:`` form's own, ``config.networks``)."""
    out: list[tuple[str, str]] = network_problems(raw)
    several = raw.get("networks") is not None
    seen: dict[str, dict[Any, int]] = {"name": {}, "unit_id": {}}
    ids: dict[tuple[str, Any], int] = {}
    entries = node_entries(raw)
    for i, (key, n, _net) in enumerate(entries):
        if not isinstance(n, dict):
            continue
        net = key.partition("nodes[")[0]  # its network by position ("networks[1]."): two named alike stay two
        v = n.get("node_id")
        if v is not None:
            if (net, v) in ids:
                out.append((f"{key}.node_id",
                            f"duplicate node_id {v!r} (also {entries[ids[net, v]][0]})"))  # fmt: skip
            else:
                ids[net, v] = i
        v = n.get("name")
        if v is not None:
            if v in seen["name"]:
                also = entries[seen["name"][v]][0]
                out.append((f"{key}.name", f"duplicate name {v!r} (also {also})"
                            + ("; node names are unique in the gateway" if several else "")))  # fmt: skip
            else:
                seen["name"][v] = i
        mb_raw = n.get("modbus")
        mb = mb_raw if isinstance(mb_raw, dict) else {}
        unit = mb.get("unit_id", n.get("node_id"))
        if unit is not None:
            if unit in seen["unit_id"]:
                other_key, other, _ = entries[seen["unit_id"][unit]]
                out.append((f"{key}.modbus.unit_id",
                            _unit_twice(unit, other_key, other, key, n) if several
                            else f"duplicate Modbus unit id {unit} (also {other_key})"))  # fmt: skip
            else:
                seen["unit_id"][unit] = i
    gw_unit = (raw.get("modbus") or {}).get("gateway_unit_id", 247)
    if gw_unit in seen["unit_id"]:
        out.append(
            (
                "modbus.gateway_unit_id",
                f"unit id {gw_unit} is also used by {entries[seen['unit_id'][gw_unit]][0]}",
            )
        )
    zen_raw = raw.get("zenoh")
    zen = zen_raw if isinstance(zen_raw, dict) else {}
    rules = zen.get("write_allow")
    if isinstance(rules, list):
        for i, rule in enumerate(rules):
            wanted = rule.get("nodes") if isinstance(rule, dict) else None
            for j, name in enumerate(wanted if isinstance(wanted, list) else []):
                if name not in seen["name"]:
                    out.append(
                        (
                            f"zenoh.write_allow[{i}].nodes[{j}]",
                            f"no node named {name!r} in nodes; nodes: "
                            + ", ".join(sorted(map(str, seen["name"]))),
                        )
                    )
    sim = raw.get("simulate") or {}
    if isinstance(sim, dict) and isinstance(sim.get("nodes"), list):
        for j, name in enumerate(sim["nodes"]):
            if name not in seen["name"]:
                out.append(
                    (f"simulate.nodes[{j}]", f"no node named {name!r} in nodes")
                )
    return out


def _unit_twice(unit: Any, first_key: str, first: Any, key: str, node: dict[str, Any]) -> str:
    """Two nodes (of two networks) on one Modbus unit, in one line naming both."""
    return (
        f"nodes {first.get('name')!r} ({first_key}) and {node.get('name')!r} ({key}) are both on "
        f"Modbus unit {unit} (modbus.unit_id defaults to the node id): give one of them its own "
        "modbus.unit_id"
    )


def parse_config(
    raw: Any,
    source: str = "<memory>",
    environ: Mapping[str, str] | None = None,
    resolve: Resolve | None = None,
) -> Config:
    """Validate an already-parsed YAML document; raise ConfigError with every problem (the
    nodes' problems too when ``resolve`` is given)."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError([f"{source}: (top level): must be a mapping of sections"])
    problems = apply_env_overrides(raw, environ or {})  # each names its variable
    base_dir = Path(source).parent if source != "<memory>" else Path.cwd()
    errors: list[tuple[str, str]] = []
    unknown: set[str] = set()  # key paths of keys that are not allowed (whoever wrote them)
    cfg: Config | None = None
    from_env = env_keys(environ or {})
    try:
        cfg = Config.model_validate({**raw, "source": source, "env_keys": from_env})
    except ValidationError as exc:
        for e in exc.errors():
            what = describe(e)
            near = nearest_key(tuple(e["loc"])) if e.get("type") == "extra_forbidden" else None
            if near is not None:
                what += f"; did you mean {near!r}?"
            if e.get("type") == "extra_forbidden":
                unknown.add(key_path(e["loc"]))
            errors.append((key_path(e["loc"]), what))
    errors += _semantic_problems(raw, base_dir)
    if cfg is not None:
        errors += resolve(cfg) if resolve is not None else []
        for view in cfg.network_views():  # a pair per network
            errors += [(view.qualify(k), m) for k, m in _pair_problems(view)]
    seen: set[tuple[str, str]] = set()
    for loc, msg in errors:
        if (loc, msg) in seen:
            continue
        seen.add((loc, msg))
        problems.append(f"{blame(loc, source, from_env, unknown=loc in unknown)}: {loc}: {msg}")
    if problems:
        raise ConfigError(problems)
    assert cfg is not None
    return cfg


def _pair_problems(cfg: Config) -> list[tuple[str, str]]:
    """A hot-standby pair (``master.redundancy``): its ids are its own, its timing is set."""
    pair = cfg.master.redundancy
    if pair is None:
        return []
    out: list[tuple[str, str]] = []
    if cfg.master.heartbeat_ms <= 0:
        out.append(
            (
                "master.heartbeat_ms",
                "a pair needs the logical master's heartbeat (> 0): the standby takes over "
                "when it is missing",
            )
        )
    hb = cfg.master.heartbeat_ms
    if pair.takeover_ms is not None and hb > 0 and pair.takeover_ms < 2 * hb:
        out.append(
            (
                "master.redundancy.takeover_ms",
                f"{pair.takeover_ms} ms is under two logical heartbeats (2 x master.heartbeat_ms "
                f"= {2 * hb} ms): one late heartbeat would look like a dead master, a lone "
                f"gateway would flap between active and standby, and two actives after a lost "
                f"claim (resolved within two heartbeats) would outlast the take-over time; "
                f"allowed: at least {2 * hb} ms "
                f"(default 3 x master.heartbeat_ms)",
            )
        )
    nodes = {n.node_id: i for i, n in enumerate(cfg.nodes)}
    for key, value in (("node_id", pair.node_id), ("peer_node_id", pair.peer_node_id)):
        if value is None:
            continue
        where = f"master.redundancy.{key}"
        if value == cfg.master.node_id:
            out.append((where, f"{value} is master.node_id (the logical master): take another id"))
        elif value in nodes:
            out.append((where, f"{value} is the node id of nodes[{nodes[value]}]"))
    if pair.peer_node_id is not None and pair.peer_node_id == pair.node_id:
        out.append(("master.redundancy.peer_node_id", "the peer's id must differ from node_id"))
    return out


def _raw_file(path: str | os.PathLike[str], environ: Mapping[str, str] | None) -> dict[str, Any] | None:
    """A config file as written (environment overrides applied), without validation; None
    when it cannot be read as a mapping."""
    try:
        raw = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None
    if not isinstance(raw, dict):
        return None
    apply_env_overrides(raw, os.environ if environ is None else environ)
    return raw


def raw_section(
    path: str | os.PathLike[str], name: str, environ: Mapping[str, str] | None = None
) -> dict[str, Any] | None:
    """Section ``name`` of a config file as written (environment overrides applied), without
    validation; None when the file or the section cannot be read as a mapping. For checks that
    still have something to say about a file that failed validation elsewhere."""
    section = (_raw_file(path, environ) or {}).get(name)
    return section if isinstance(section, dict) else None


def raw_list(
    path: str | os.PathLike[str], name: str, environ: Mapping[str, str] | None = None
) -> list[Any] | None:
    """The list ``name`` of a config file as written (``networks``), as ``raw_section``."""
    section = (_raw_file(path, environ) or {}).get(name)
    return section if isinstance(section, list) else None


def yaml_error_line(source: str, text: str, exc: yaml.YAMLError) -> str:
    """A YAML syntax error as one line at the line of the mistake, quoted. PyYAML marks where
    it gave up (``problem_mark``: for ``port 5020`` without its colon, the next key, lines
    later) and where the construct it was reading began (``context_mark``). The scanner's
    context is the token in error (``port 5020``) and a flow collection's is its opening
    bracket (left unclosed); a block collection's context is where the section began, so there
    the problem mark is the line. A mark on a blank or comment line steps back to the last line
    with text."""
    problem_mark = getattr(exc, "problem_mark", None)
    context_mark = getattr(exc, "context_mark", None)
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    context = getattr(exc, "context", None)
    mark = problem_mark
    token_context = isinstance(exc, yaml.scanner.ScannerError) or "flow" in str(context)
    if token_context and context_mark is not None and (mark is None or context_mark.line <= mark.line):
        mark = context_mark
    if mark is None:
        return f"{source}: YAML syntax error: {problem}"
    lines = text.splitlines()
    n = min(mark.line, len(lines) - 1)
    while n > 0 and (not lines[n].strip() or lines[n].lstrip().startswith("#")):
        n -= 1
    where = f"line {n + 1}" + (f", column {mark.column + 1}" if n == mark.line else "")
    why = f"{problem} ({context})" if context else problem
    quoted = lines[n].strip() if lines else ""
    return f"{source}: {where}: YAML syntax error: {why}: {quoted!r}"


def load_config(
    path: str | os.PathLike[str],
    environ: Mapping[str, str] | None = None,
    resolve: Resolve | None = None,
) -> Config:
    """Read and validate a config file; ``environ`` defaults to ``os.environ``; ``resolve`` as
    for ``parse_config``."""
    p = Path(path)
    source = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError([f"{source}: file does not exist"]) from None
    except OSError as exc:
        raise ConfigError([f"{source}: cannot read: {exc.strerror}"]) from None
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError([yaml_error_line(source, text, exc)]) from None
    environ = os.environ if environ is None else environ
    if raw is None or raw == {}:
        raise ConfigError(
            [f"{source}: the file is empty; a config needs at least can: and nodes: "
             "(see config/demo.yaml)"]
        )
    return parse_config(raw, source, environ, resolve)
