"""How a command of the command line loads its configuration: checked as at every start
(``gateway.checks``: validated, its nodes resolved once and cross-checked) and, for a command that opens the CAN bus, with an interface python-can
can load; where the configuration is when ``-c`` is left out; the exit codes of the command line.

Imports: gateway.checks, gateway.config, gateway.device.resolved, gateway.bus.can_backend (inside the bus check).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from gateway.checks import load_checked
from gateway.config import Config, ConfigError
from gateway.device.resolved import Resolved

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
    Every problem in one run: the ``can:`` keys are checked also when the file has problems
    elsewhere (read from the file as written then)."""
    from gateway.bus.can_backend import can_section_problems, driver_problem, interface_problem
    from gateway.config import CAN_INTERFACE_MISSING, blame, env_keys, raw_section

    problems: list[str] = []
    cfg: Config | None = None
    loaded: Resolved | None = None
    try:
        loaded = load(path)
        cfg = loaded.cfg
    except ConfigError as exc:
        problems += exc.problems
    from_env = env_keys(os.environ)
    source = cfg.source if cfg is not None else str(path)
    if cfg is not None:
        section: dict[str, Any] | None = cfg.can.model_dump(exclude_none=True)
        named = "interface" in cfg.can.model_fields_set  # written in the file or the environment
    else:
        section = raw_section(path, "can")
        named = section is not None and isinstance(section.get("interface"), str)
    if section is not None:
        if not named:
            problems.append(f"{source}: can.interface: {CAN_INTERFACE_MISSING}")
        else:
            problem = interface_problem(section["interface"]) or driver_problem(section["interface"])
            if problem is not None:
                where = blame("can.interface", source, from_env)
                problems.append(f"{where}: can.interface: {problem}")
            else:
                problems += [
                    f"{blame(k, source, from_env)}: {k}: {why}"
                    for k, why in can_section_problems(section)
                ]
    if problems:
        raise ConfigError(problems)
    assert loaded is not None
    return loaded
