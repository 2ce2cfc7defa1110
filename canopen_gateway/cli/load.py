"""How a command of the command line loads its configuration: checked as at every start
(``canopen_gateway.checks``: validated, its nodes resolved once and cross-checked) and, for a command that opens the CAN bus, with an interface python-can
can load; where the configuration is when ``-c`` is left out; the network a command that opens
one bus works on (``--network``: ``on_network``); the exit codes of the command line.

Imports: canopen_gateway.checks, canopen_gateway.config, canopen_gateway.device.resolved, canopen_gateway.bus.can_backend (inside the bus check).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping
from typing import Any

from canopen_gateway.checks import load_checked
from canopen_gateway.config import Config, ConfigError
from canopen_gateway.device.resolved import Resolved

EXIT_CONFIG = 2
EXIT_FAILED = 1

#: where a command finds its configuration when ``-c`` is left out: this variable, else the file
CONFIG_ENV = "CANOPEN_GATEWAY_CONFIG"
DEFAULT_CONFIG = "/etc/canopen-gateway/config.yaml"


def default_config(environ: Mapping[str, str] | None = None, default: str = DEFAULT_CONFIG) -> str:
    """The configuration of a command given no ``-c``: ``$CANOPEN_GATEWAY_CONFIG``, else
    ``/etc/canopen-gateway/config.yaml`` when it exists; else ConfigError naming both."""
    env = os.environ if environ is None else environ
    given = env.get(CONFIG_ENV, "").strip()
    if given:
        if not os.path.exists(given):  # say where the path came from: no -c was given
            raise ConfigError([f"error: {given}: file does not exist (named by {CONFIG_ENV}; or give -c FILE)"])
        return given
    if os.path.isfile(default):
        return default
    raise ConfigError(
        [f"error: no configuration: give -c FILE, or set {CONFIG_ENV}=FILE, or install one at {default}"]
    )


def load(path: str) -> Resolved:
    """The config and its resolved nodes (``cfg, nodes = load(path)``)."""
    return load_checked(path)


def load_for_bus(path: str) -> Resolved:
    """The config of a command that opens the CAN bus: also refuses an interface python-can
    cannot load (unknown name, plug-in not installed), in one line, before anything starts.
    Every problem in one run: the ``can:`` keys (of every network) are checked also when the
    file has problems elsewhere (read from the file as written then)."""
    problems: list[str] = []
    cfg: Config | None = None
    loaded: Resolved | None = None
    try:
        loaded = load(path)
        cfg = loaded.cfg
    except ConfigError as exc:
        problems += exc.problems
    source = cfg.source if cfg is not None else str(path)
    for key, section, named in _can_sections(path, cfg):
        problems += _can_problems(source, key, section, named)
    if problems:
        raise ConfigError(problems)
    assert loaded is not None
    return loaded


def _can_sections(path: str, cfg: Config | None) -> list[tuple[str, dict[str, Any], bool]]:
    """Each network's ``can:`` section with its key (``can``, ``networks[1].can``) and whether
    it names its interface: from the config, else as the file writes it."""
    from canopen_gateway.config import raw_list, raw_section

    if cfg is not None:
        return [
            (view.qualify("can"), view.can.model_dump(exclude_none=True),
             "interface" in view.can.model_fields_set)  # written in the file or the environment
            for view in cfg.network_views()
        ]  # fmt: skip
    out = []
    nets = raw_list(path, "networks")
    written = [(f"networks[{k}].can", n.get("can")) for k, n in enumerate(nets or []) if isinstance(n, dict)]
    for key, section in written if nets is not None else [("can", raw_section(path, "can"))]:
        if isinstance(section, dict):
            out.append((key, section, isinstance(section.get("interface"), str)))
    return out


def _can_problems(source: str, key: str, section: dict[str, Any], named: bool) -> list[str]:
    """One ``can:`` section's problems: no interface named, one python-can cannot load, keys
    its bus class does not take."""
    from canopen_gateway.bus.can_backend import (
        can_section_problems,
        driver_problem,
        interface_problem,
    )
    from canopen_gateway.config import CAN_INTERFACE_MISSING, blame, env_keys

    from_env = env_keys(os.environ)
    if not named:
        return [f"{source}: {key}.interface: {CAN_INTERFACE_MISSING}"]
    problem = interface_problem(section["interface"]) or driver_problem(section["interface"])
    if problem is not None:
        return [f"{blame(f'{key}.interface', source, from_env)}: {key}.interface: {problem}"]
    return [
        f"{blame(k, source, from_env)}: {k}: {why}"
        for k, why in ((key + k.removeprefix("can"), why) for k, why in can_section_problems(section))
    ]


def on_network(loaded: Resolved, network: str | None, command: str, node: str | None = None) -> Resolved:
    """The config of one network (``Config.network_view``: its can, master and nodes) and its
    nodes, for a command that opens one bus: ``network`` (``--network``), or the only one;
    with several networks and none named, the command is refused in one line with their names
    (exit 2), and the network of ``node`` when a node name is given."""
    cfg, nodes = loaded
    names = cfg.network_names()
    if network is None and len(names) == 1:
        network = names[0]
    if network not in names:
        if network is None:
            on = ""
            if node is not None and node in nodes:
                on = f"; node {node} is on network {cfg.network_of(node)}"
            why = f"the config has {len(names)} networks: give --network NAME (one of: {', '.join(names)}){on}"
        else:
            why = f"no network named {network!r}; networks: {', '.join(names)}"
        print(f"error: {cfg.source}: {command}: {why}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    view = cfg.network_view(network)
    if node is not None and node in nodes and node not in {n.name for n in view.nodes}:
        print(f"error: {cfg.source}: {command}: node {node} is on network {cfg.network_of(node)}, not "
              f"{network}: give --network {cfg.network_of(node)}", file=sys.stderr)  # fmt: skip
        raise SystemExit(EXIT_CONFIG)
    return Resolved(view, {n.name: nodes[n.name] for n in view.nodes})
