"""The gateway's configuration as data: the pydantic models of every section of the YAML file
(``gateway:``, ``can:``, ``master:``, ``nodes:``, ``networks:``, ``modbus:``, ``zenoh:``,
``health:``, ``web:``, ``ascii:``, ``simulate:``, ``journal:`` from ``config.journal``,
``nodes:`` from ``config.node``, ``zenoh:`` from ``config.zenoh``) with the rules one field or one section can check itself
(ranges, patterns, key expressions, networks, TLS roles, token length).

Several CAN networks: ``networks:`` lists them, each with its own ``can:``, ``master:`` and
``nodes:``; the single-network form (top-level ``can:``, ``master:``, ``nodes:``) is one network
named ``default``. ``Config.network_sections()`` gives the networks of either form;
``Config.network_view(name)`` a config of one network (its ``can``, ``master`` and ``nodes``,
the shared sections as they are), which the parts of one network (its driver and master, the
commissioning tools, the checks of one bus) read as they read a single-network config. In the
``networks:`` form ``Config.nodes`` is every network's nodes (names are unique in the gateway)
and ``can`` / ``master`` are the first network's.

What a section cannot see (duplicates across nodes, names that refer to nodes, profiles and
EDS files) is checked when the file is loaded (``config.load``).

Imports: pydantic, config.journal, config.node (the ``nodes:`` entries), config.zenoh.
Nothing of bus/,
modbus/, zenoh_bridge/, checks.
"""

from __future__ import annotations

import ipaddress
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    field_validator,
    model_serializer,
    model_validator,
)

from canopen_gateway.config.journal import JournalSection
from canopen_gateway.config.node import NodeConfig
from canopen_gateway.config.zenoh import ZenohSection


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class GatewaySection(_Model):
    name: str = Field(default="gateway", pattern=r"^[A-Za-z0-9_\-]+$")
    log_level: Literal["debug", "info", "warning", "error"] = "info"


class CanSection(BaseModel):
    """Passed through to ``can.Bus(**can)``: interface, channel, bitrate and backend kwargs."""

    model_config = ConfigDict(extra="allow")
    interface: str = "virtual"
    channel: str | int = "canopen-gateway"
    bitrate: int | None = Field(default=None, gt=0)
    reopen_backoff_s: float = Field(default=1.0, gt=0, le=60)

    def bus_kwargs(self) -> dict[str, Any]:
        kw = self.model_dump(exclude={"reopen_backoff_s"}, exclude_none=True)
        return kw

    def words(self) -> dict[str, Any]:
        """The bus as the console and the catalogue show it: interface, channel, bitrate."""
        return {"interface": self.interface, "channel": str(self.channel), "bitrate": self.bitrate}


class PairSection(_Model):
    """``master.redundancy``: this gateway's own identity in a hot-standby pair (CiA 302-2
    flying master; docs/redundancy.md). Both gateways of a pair run the same config but this
    section."""

    node_id: int = Field(
        ge=1, le=127, description="this gateway's own id in the pair: its heartbeat and claims"
    )
    priority: int = Field(
        default=0, ge=0, le=255, description="CiA 302-2 1F90h:03: lower wins; equal: lower node_id"
    )
    takeover_ms: int | None = Field(
        default=None,
        ge=10,
        le=60_000,
        description="the active gateway's heartbeat missing this long: take over "
        "(default 3 x master.heartbeat_ms)",
    )
    priority_slot_ms: int = Field(default=200, ge=0, le=10_000, description="CiA 302-2 1F90h:04")
    device_slot_ms: int = Field(default=2, ge=0, le=1000, description="CiA 302-2 1F90h:05")
    detect_cycle_ms: int = Field(
        default=4000,
        ge=100,
        le=600_000,
        description="CiA 302-2 1F90h:06: the active gateway's multiple-master check (76h) period",
    )
    peer_node_id: int | None = Field(
        default=None, ge=1, le=127, description="the other gateway's own id: its heartbeat is watched"
    )


class MasterSection(_Model):
    node_id: int = Field(default=127, ge=1, le=127, description="the gateway's own node id")
    heartbeat_ms: int = Field(default=1000, ge=0, le=65535, description="0 = no heartbeat")
    sync_period_ms: float = Field(default=0, ge=0, le=65535, description="0 = no SYNC")
    sync_external: bool = Field(
        default=False,
        description="another master produces SYNC on this bus (with sync_period_ms 0)",
    )
    sdo_timeout_s: float = Field(default=0.5, gt=0, le=30)
    sdo_retries: int = Field(default=1, ge=0, le=10)
    boot_timeout_s: float = Field(default=10.0, gt=0, le=3600)
    heartbeat_timeout_multiple: float = Field(default=1.5, ge=1.0, le=10)
    probe_at_start: bool = True
    sdo_cache_ms: int = Field(
        default=1000,
        ge=0,
        le=3_600_000,
        description="SDO-backed values read north are served from a cache this young (0 = always read)",
    )
    #: a hot-standby pair: this gateway's own id and priority (off unless given)
    redundancy: PairSection | None = None


#: the default of ``allowed_networks``: this machine only
LOOPBACK_NETWORKS = ("127.0.0.0/8", "::1/128")


def _check_networks(networks: list[str]) -> None:
    for n in networks:
        try:
            ipaddress.ip_network(n, strict=False)
        except ValueError as exc:
            raise ValueError(f"allowed_networks: {n!r} is not a network ({exc})") from None


class ModbusTls(_Model):
    """Modbus/TCP Security (TLS, mutual X.509 authentication, roles): a second listener."""

    host: str | None = Field(default=None, description="default: modbus.host")
    port: int = Field(default=802, ge=0, le=65535, description="802 is the standard's port")
    cert: str = Field(description="our certificate (PEM, chain allowed)")
    key: str = Field(description="its private key (PEM)")
    ca: str | None = Field(default=None, description="CA certificates (PEM) that sign clients")
    require_client_cert: bool = True
    roles: dict[str, Literal["read", "write"]] = Field(
        default_factory=lambda: dict[str, Literal["read", "write"]](
            Operator="write", Viewer="read"
        ),
        description="role (certificate extension 1.3.6.1.4.1.50316.802.1) -> read or write",
    )
    default_role: str | None = Field(
        default=None, description="role of a client whose certificate has none; none: refused"
    )
    crl: str | None = Field(
        default=None,
        description="certificate revocation list(s) of the CA (PEM): a revoked client is refused",
    )

    @model_validator(mode="after")
    def _roles(self) -> ModbusTls:
        if self.crl and not self.ca:
            raise ValueError("crl needs ca (the CA file whose revocations it lists)")
        if self.require_client_cert and not self.ca:
            raise ValueError("require_client_cert: true needs ca (the CA file that signs clients)")
        if self.default_role is not None and self.default_role not in self.roles:
            raise ValueError(
                f"default_role: {self.default_role!r} is not in roles ({', '.join(self.roles)})"
            )
        return self


class ModbusSection(_Model):
    enabled: bool = True
    plain: bool = Field(default=True, description="plain Modbus TCP on host:port (false: TLS only)")
    tls: ModbusTls | None = None
    host: str = "127.0.0.1"
    port: int = Field(default=5020, ge=0, le=65535)
    layout: Literal["per_node", "flat"] = "per_node"
    gateway_unit_id: int = Field(default=247, ge=1, le=247)
    flat_unit_id: int = Field(default=1, ge=1, le=247)
    flat_stride: int = Field(default=200, ge=50, le=10000)
    word_order: Literal["big", "little"] = "big"
    read_only: bool = False
    allowed_networks: list[str] = Field(default_factory=lambda: list(LOOPBACK_NETWORKS))
    max_connections: int = Field(
        default=64,
        ge=1,
        le=10_000,
        description="Modbus connections at once (plain and TLS together); past it a new one is closed",
    )
    max_connections_per_client: int = Field(
        default=8, ge=1, le=10_000, description="connections at once from one client address"
    )
    idle_timeout_s: float = Field(
        default=300.0,
        ge=0,
        le=86_400,
        description="a connection that sends nothing this long is closed; 0 = never",
    )
    write_timeout_s: float = Field(default=2.0, gt=0, le=60)
    watchdog_ms: int = Field(
        default=0,
        ge=0,
        le=3_600_000,
        description="no request of a client that may write for this long: safe outputs; 0 = off",
    )
    watchdog_on_disconnect: bool = Field(
        default=False,
        description="safe outputs when the last client that may write disconnected and none "
        "came back with a request within watchdog_ms (at once when watchdog_ms is 0)",
    )

    @model_validator(mode="after")
    def _nets(self) -> ModbusSection:
        if not self.plain and self.tls is None:
            raise ValueError("plain: false needs tls (nothing would serve Modbus)")
        if self.max_connections_per_client > self.max_connections:
            raise ValueError(
                f"max_connections_per_client ({self.max_connections_per_client}) is above "
                f"max_connections ({self.max_connections})"
            )
        _check_networks(self.allowed_networks)
        return self


class AsciiSection(_Model):
    """The CiA 309-3 ASCII gateway on TCP (``canopen_gateway/ascii``). Off unless the section is given;
    ``enabled: false`` turns a given section off."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = Field(default=60000, ge=0, le=65535, description="0 = any free port")
    writes: bool = Field(default=False, description="SDO downloads and NMT commands allowed")
    events: bool = Field(
        default=False, description="event lines (BOOT_UP, EMCY, heartbeat) to every client"
    )
    allowed_networks: list[str] = Field(
        default_factory=lambda: list(LOOPBACK_NETWORKS),
        description="client addresses served; any other connection is closed at once",
    )

    @model_validator(mode="after")
    def _nets(self) -> AsciiSection:
        _check_networks(self.allowed_networks)
        return self


class CommandSocketSection(_Model):
    """The command line's local way into the running gateway when its bus is in-process
    (``can.interface: virtual``): a Unix socket only this user can open (``canopen_gateway/command_socket``)."""

    enabled: bool = Field(default=True, description="listen on it (with an in-process bus)")
    path: str | None = Field(
        default=None, description="default: the user's runtime directory, named by the config file"
    )


class HealthTls(_Model):
    """HTTPS on the health port: /healthz, /livez, /metrics and the web console over TLS."""

    cert: str = Field(min_length=1, description="the server's certificate (PEM, chain allowed), relative to this file")
    key: str = Field(min_length=1, description="its private key (PEM, without a passphrase), relative to this file")


class HealthSection(_Model):
    host: str = "127.0.0.1"
    port: int = Field(default=0, ge=0, le=65535, description="0 = off")
    tls: HealthTls | None = Field(
        default=None, description="serve HTTPS instead of HTTP on this port (plain HTTP gets no answer)"
    )


#: the smallest web token accepted: guessing one must not be a matter of minutes
WEB_TOKEN_MIN_LENGTH = 12
#: the one rule for a token of digits only, whether the file or CANOPEN_GATEWAY__WEB__TOKEN
#: gives it (quoted or not): refused, it is a number anyone may guess
WEB_TOKEN_DIGITS = (
    "a token of digits only is refused, in the file (quoted or not) as in "
    "CANOPEN_GATEWAY__WEB__TOKEN: mix in letters (token: \"a long random text\")"
)


class WebSection(_Model):
    """The web console on the health HTTP server (``health.port``; off when that is 0)."""

    enabled: bool = Field(default=True, description="serve the console next to /healthz")
    writes: bool = Field(
        default=False, description="the commissioning page (SDO, NMT, set points, LSS)"
    )
    token: str | None = Field(
        default=None,
        description="the operators' password (journal, bus monitor, SDO reads, faults, "
        "commissioning); or CANOPEN_GATEWAY__WEB__TOKEN",
    )
    token_file: str | None = Field(
        default=None, description="a file holding the token (first line), instead of token"
    )
    allowed_hosts: list[str] | None = Field(
        default=None,
        description="Host header names the console answers (DNS rebinding); default: the bind "
        "address, the address a request arrived at, localhost and this machine's names; '*' = any",
    )

    @field_validator("token", mode="before")
    @classmethod
    def _token_text(cls, v: Any) -> Any:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            raise ValueError(f"YAML read a number here; {WEB_TOKEN_DIGITS}")
        return v

    @field_validator("token")
    @classmethod
    def _token_not_digits(cls, v: str | None) -> str | None:
        # one rule, from the file or the environment (whose text keys are taken as given: a
        # value quoted in the shell's way, '123...', is the same digits)
        core = v[1:-1] if v is not None and len(v) >= 2 and v[0] == v[-1] and v[0] in "'\"" else v
        if core is not None and core.isdigit():
            raise ValueError(WEB_TOKEN_DIGITS)
        return v

    @model_validator(mode="after")
    def _token(self) -> WebSection:
        if self.token is not None and self.token_file is not None:
            raise ValueError("token and token_file: give one, not both")
        if self.writes and not self.token and not self.token_file:
            raise ValueError(
                "writes: true needs a token (web.token, web.token_file, or the environment "
                "variable CANOPEN_GATEWAY__WEB__TOKEN)"
            )
        if self.token is not None and len(self.token) < WEB_TOKEN_MIN_LENGTH:
            raise ValueError(f"token: at least {WEB_TOKEN_MIN_LENGTH} characters")

        return self


class SimulateSection(_Model):
    """Nodes simulated in-process on the configured bus (demos, tests, commissioning)."""

    nodes: list[str] | Literal["all"] = Field(default_factory=list)
    motion: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="per node name: motion model (kind ramp|sine|random_walk|hold, min, max, speed...)",
    )
    options: dict[str, dict[str, Any]] = Field(
        default_factory=dict, description="per node name: simulator options"
    )


#: the one network of the single-network form (top-level ``can``, ``master``, ``nodes``)
DEFAULT_NETWORK = "default"
#: the sections a network has of its own (``networks[].can`` ...; top-level in the other form)
NETWORK_KEYS = ("can", "master", "nodes")


class NetworkSection(_Model):
    """One CAN network of the gateway (``networks[]``): its bus, its master and its nodes, as
    the top-level ``can:``, ``master:`` and ``nodes:`` of the single-network form."""

    name: str = Field(pattern=r"^[a-z0-9_\-]+$", description="in logs, /healthz, metrics, the console")
    can: CanSection = Field(default_factory=CanSection)
    master: MasterSection = Field(default_factory=MasterSection)
    nodes: list[NodeConfig] = Field(default_factory=list)


class Config(_Model):
    gateway: GatewaySection = Field(default_factory=GatewaySection)
    can: CanSection = Field(default_factory=CanSection)
    master: MasterSection = Field(default_factory=MasterSection)
    nodes: list[NodeConfig] = Field(default_factory=list)
    #: several CAN networks, each with its own can, master and nodes (None: the single form);
    #: at most 8 (the gateway block of unit 247 has a register per network, docs/modbus.md)
    networks: list[NetworkSection] | None = Field(default=None, max_length=8)
    modbus: ModbusSection = Field(default_factory=ModbusSection)
    zenoh: ZenohSection = Field(default_factory=ZenohSection)
    health: HealthSection = Field(default_factory=HealthSection)
    web: WebSection = Field(default_factory=WebSection)
    ascii: AsciiSection | None = None  # CiA 309-3 ASCII gateway: off unless given
    command_socket: CommandSocketSection = Field(default_factory=CommandSocketSection)
    simulate: SimulateSection = Field(default_factory=SimulateSection)
    journal: JournalSection = Field(default_factory=JournalSection)  # store and forward

    #: where the file was loaded from (for resolving relative profile paths and messages)
    source: str = Field(default="<memory>", exclude=True)
    #: key path -> the environment variable that set it (``config.env.env_keys``): a problem
    #: found after loading is blamed on the variable, as one found while loading is
    env_keys: dict[str, str] = Field(default_factory=dict, exclude=True)
    #: a view of one network of the ``networks:`` form (``network_view``): its key paths start
    #: ``networks[k].``; empty for a whole config
    key_prefix: str = Field(default="", exclude=True)

    @model_validator(mode="after")
    def _flatten(self) -> Config:
        """``networks:``: ``nodes`` are every network's, ``can`` and ``master`` the first's
        (given together with the top-level keys, the loader refuses the file)."""
        nets = self.networks
        if nets and not (NETWORK_KEYS_SET & self.model_fields_set):
            self.nodes = [n for net in nets for n in net.nodes]
            self.can = nets[0].can
            self.master = nets[0].master
        return self

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> Any:
        """Written back as it was read: the ``networks:`` form without the top-level copies."""
        out = handler(self)
        if isinstance(out, dict):
            for key in NETWORK_KEYS if self.networks is not None else ("networks",):
                out.pop(key, None)
        return out

    # ------------------------------------------------------------------ networks
    def network_sections(self) -> list[NetworkSection]:
        """The networks of either form (the single form: one named ``default``, whose sections
        are the top-level ones, the same objects)."""
        if self.networks is not None:
            return list(self.networks)
        return [
            NetworkSection.model_construct(
                name=DEFAULT_NETWORK, can=self.can, master=self.master, nodes=self.nodes
            )
        ]

    def network_names(self) -> list[str]:
        return [net.name for net in self.network_sections()]

    def network_view(self, name: str) -> Config:
        """The config of network ``name`` alone: its ``can``, ``master`` and ``nodes``; the
        shared sections are this config's (the same objects). The config itself in the
        single-network form, or when it is a network's view already. KeyError for an unknown
        name."""
        for k, net in enumerate(self.network_sections()):
            if net.name == name:
                return self if self.networks is None or self.key_prefix else self._view(k, net)
        raise KeyError(name)

    def _view(self, k: int, net: NetworkSection) -> Config:
        return self.model_copy(update={
            "can": net.can, "master": net.master, "nodes": net.nodes, "networks": [net],
            "key_prefix": f"networks[{k}].",
        })  # fmt: skip

    def network_views(self) -> list[Config]:
        """``network_view`` of every network, in configured order."""
        return [self.network_view(name) for name in self.network_names()]

    def network_of(self, node: str) -> str:
        """The name of the network node ``node`` is on (KeyError: no such node)."""
        for net in self.network_sections():
            if any(n.name == node for n in net.nodes):
                return net.name
        raise KeyError(node)

    def qualify(self, key: str) -> str:
        """A key path of this config as the file spells it: a network view's ``nodes[0]``,
        ``can.x``, ``master.x`` under its ``networks[k].``; a whole ``networks:`` config's
        ``nodes[i]`` (every network's nodes in order) as ``networks[k].nodes[j]``."""
        head = key.split(".", 1)[0].split("[", 1)[0]
        if head not in NETWORK_KEYS:
            return key
        if self.key_prefix:
            return self.key_prefix + key
        if self.networks is None or head != "nodes" or not key.startswith("nodes["):
            return key
        index, _, rest = key[len("nodes["):].partition("]")
        if not index.isdigit():
            return key
        i = int(index)
        for k, net in enumerate(self.networks):
            if i < len(net.nodes):
                return f"networks[{k}].nodes[{i}]{rest}"
            i -= len(net.nodes)
        return key

    def node(self, name: str) -> NodeConfig:
        for n in self.nodes:
            if n.name == name:
                return n
        raise KeyError(name)

    def simulated_nodes(self) -> list[NodeConfig]:
        if self.simulate.nodes == "all":
            return list(self.nodes)
        wanted = set(self.simulate.nodes)
        return [n for n in self.nodes if n.name in wanted]

    @property
    def base_dir(self) -> Path:
        return Path(self.source).parent if self.source != "<memory>" else Path.cwd()

    def path_of(self, value: str) -> Path:
        """A file setting's path: relative to the config file unless absolute."""
        p = Path(value).expanduser()
        return p if p.is_absolute() else self.base_dir / p

    def web_token(self) -> str | None:
        """The console's token: ``web.token``, or the first line of ``web.token_file`` (OSError
        when it cannot be read; ``canopen-gateway check`` and every start check it first)."""
        if self.web.token_file is None:
            return self.web.token
        return read_secret(self.path_of(self.web.token_file))


def read_secret(path: Path) -> str:
    """The secret a file holds: its first line, without surrounding blanks."""
    text = path.read_text(encoding="utf-8")
    return text.splitlines()[0].strip() if text.strip() else ""


NETWORK_KEYS_SET = frozenset(NETWORK_KEYS)


#: A config that opens the bus must say which one: the in-process ``virtual`` bus is not a
#: silent default (``can.interface`` must be written; checked by the commands that open the bus).
CAN_INTERFACE_MISSING = (
    "required key is missing: the CAN interface python-can opens (socketcan, pcan, kvaser, "
    "ixxat, slcan, remote, ...; virtual for simulated devices in this process, without hardware)"
)
