"""The gateway's configuration: one YAML file validated by pydantic, plus environment overrides.

Every problem is reported as one line naming the file, the key path (``nodes[2].node_id``) and
what is allowed; all problems of a file are collected before reporting. Environment variables
``CANOPEN_GATEWAY__SECTION__KEY=value`` override single keys (list items by index:
``CANOPEN_GATEWAY__NODES__0__NODE_ID=5``); values are parsed as YAML scalars/flow lists.

This package checks what one file can say about itself (schema, duplicates, key expressions).
A node's profile and EDS, and what the node asks of them, are checked by the node's resolution
(``canopen_gateway.device.resolved``), which hands itself to ``load_config`` / ``parse_config`` as
``resolve``: its problems join the file's, in one ConfigError. The checks across the config,
the profiles/EDS and the compiled register map (``canopen-gateway check``) live in
``canopen_gateway.checks``, which imports this package; this package imports neither it nor modbus/.

The package, one module per part, re-exported here (``from canopen_gateway.config import Config``):

- ``model``: the sections of the file (pydantic models) and what each checks of itself;
- ``load``: ``load_config`` / ``parse_config`` and the checks across entries of one file;
- ``env``: the ``CANOPEN_GATEWAY__`` environment overrides and whom a problem blames;
- ``errors``: ``ConfigError`` and how a problem is worded;
- ``journal``: the ``journal:`` section;
- ``zenoh``: the ``zenoh:`` section;
- ``node``: the ``nodes:`` entries and ``NodeConfig.setup``, the record the device knowledge
  reads;
- ``keyexpr``: a Zenoh key expression of the file checked (without zenoh).

Imports: model, node, load, env, errors, journal, zenoh (its own modules). Nothing of bus/, modbus/, zenoh_bridge/,
checks.
"""

from __future__ import annotations

from canopen_gateway.config.env import (
    ENV_PREFIX,
    ENV_TEXT_KEYS,
    apply_env_overrides,
    blame,
    env_keys,
)
from canopen_gateway.config.errors import ConfigError, nearest_key
from canopen_gateway.config.journal import JournalSection
from canopen_gateway.config.load import load_config, parse_config, raw_list, raw_section
from canopen_gateway.config.model import (
    CAN_INTERFACE_MISSING,
    DEFAULT_NETWORK,
    LOOPBACK_NETWORKS,
    WEB_TOKEN_MIN_LENGTH,
    AsciiSection,
    CanSection,
    CommandSocketSection,
    Config,
    GatewaySection,
    HealthSection,
    HealthTls,
    MasterSection,
    ModbusSection,
    ModbusTls,
    NetworkSection,
    SimulateSection,
    WebSection,
    read_secret,
)
from canopen_gateway.config.node import (
    ExternalHeartbeat,
    GuardingBitSettings,
    NodeConfig,
    NodeModbus,
    Obj,
    PdoSetting,
    SdoWrite,
    SignalOverride,
)
from canopen_gateway.config.zenoh import (
    ZenohAuth,
    ZenohHistory,
    ZenohSection,
    ZenohTls,
    ZenohWriteRule,
    placeholder_problem,
)

__all__ = [
    "AsciiSection",
    "CommandSocketSection",
    "CAN_INTERFACE_MISSING",
    "CanSection",
    "DEFAULT_NETWORK",
    "NetworkSection",
    "Config",
    "ConfigError",
    "ENV_PREFIX",
    "ENV_TEXT_KEYS",
    "ExternalHeartbeat",
    "GatewaySection",
    "GuardingBitSettings",
    "HealthSection",
    "HealthTls",
    "JournalSection",
    "MasterSection",
    "ModbusSection",
    "ModbusTls",
    "NodeConfig",
    "NodeModbus",
    "Obj",
    "PdoSetting",
    "SdoWrite",
    "SignalOverride",
    "SimulateSection",
    "LOOPBACK_NETWORKS",
    "WEB_TOKEN_MIN_LENGTH",
    "WebSection",
    "ZenohAuth",
    "ZenohHistory",
    "ZenohSection",
    "ZenohTls",
    "ZenohWriteRule",
    "placeholder_problem",
    "read_secret",
    "apply_env_overrides",
    "blame",
    "env_keys",
    "load_config",
    "raw_list",
    "raw_section",
    "nearest_key",
    "parse_config",
]
