"""How a command of the command line loads its configuration: checked as at every start
(``gateway.checks``) and, for a command that opens the CAN bus, with an interface python-can
can load; the exit codes of the command line.

Imports: gateway.checks, gateway.config, gateway.bus.can_backend (inside the bus check).
"""

from __future__ import annotations

import os

from gateway.checks import load_checked_config
from gateway.config import Config, ConfigError

EXIT_CONFIG = 2
EXIT_FAILED = 1


def load(path: str) -> Config:
    return load_checked_config(path)


def load_for_bus(path: str) -> Config:
    """The config of a command that opens the CAN bus: also refuses an interface python-can
    cannot load (unknown name, plug-in not installed), in one line, before anything starts."""
    from gateway.bus.can_backend import can_section_problems, driver_problem, interface_problem
    from gateway.config import CAN_INTERFACE_MISSING, blame, env_keys

    cfg = load(path)
    from_env = env_keys(os.environ)
    if "interface" not in cfg.can.model_fields_set:  # written in the file or the environment
        raise ConfigError([f"{cfg.source}: can.interface: {CAN_INTERFACE_MISSING}"])
    problem = interface_problem(cfg.can.interface) or driver_problem(cfg.can.interface)
    if problem is not None:
        raise ConfigError([f"{blame('can.interface', cfg.source, from_env)}: can.interface: {problem}"])
    problems = can_section_problems(cfg.can.model_dump(exclude_none=True))
    if problems:
        raise ConfigError([f"{blame(k, cfg.source, from_env)}: {k}: {why}" for k, why in problems])
    return cfg
