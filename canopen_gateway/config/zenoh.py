"""The ``zenoh:`` section: the Zenoh session (mode, endpoints, prefix, TLS, authentication,
access control), what the bridge publishes and keeps for late subscribers (``history``), and
the writes and SDO reads it takes (``writes``, ``write_allow``: the rules each write must
match; ``reads``); with the rules one section can check itself (key expressions, a password
with its user and never the examples' placeholder, a prefix without wildcards).

Imports: pydantic, config.keyexpr (the key expressions' check). Nothing of zenoh_bridge/.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from canopen_gateway.config import keyexpr


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ZenohTls(_Model):
    """TLS of the Zenoh links (``tls/`` endpoints), passed to zenoh's ``transport/link/tls``."""

    root_ca_certificate: str | None = Field(default=None, description="CA file to trust (PEM)")
    listen_certificate: str | None = Field(default=None, description="our certificate (PEM)")
    listen_private_key: str | None = Field(default=None, description="its private key (PEM)")
    connect_certificate: str | None = Field(default=None, description="client cert for mTLS")
    connect_private_key: str | None = Field(default=None, description="its private key (PEM)")
    enable_mtls: bool | None = None
    verify_name_on_connect: bool | None = None


#: what a Zenoh client may be allowed to do south (``zenoh.write_allow[].operations``)
ZenohWriteOperation = Literal["set", "sdo_write", "nmt"]
ZENOH_WRITE_OPERATIONS: tuple[ZenohWriteOperation, ...] = ("set", "sdo_write", "nmt")


class ZenohWriteRule(_Model):
    """One allow rule of ``zenoh.write_allow``: a write is allowed when it matches every list
    given (an empty list matches everything)."""

    operations: list[ZenohWriteOperation] = Field(
        default_factory=lambda: list(ZENOH_WRITE_OPERATIONS),
        description="set (set/<signal>, set), sdo_write (SDO download), nmt",
    )
    nodes: list[str] = Field(default_factory=list, description="node names; empty = every node")
    keys: list[str] = Field(
        default_factory=list, description="key expressions the query key must be in; empty = any"
    )

    @model_validator(mode="after")
    def _keys(self) -> ZenohWriteRule:
        for k in self.keys:
            why = keyexpr.problem(k)
            if why:
                raise ValueError(f"keys: {why}")
        return self


#: passwords the examples of this project and of Zenoh's documentation wrote: never a real one
PLACEHOLDER_PASSWORDS = frozenset({"change-me", "changeme", "change_me"})


def placeholder_problem(secret: str) -> str | None:
    """Why ``secret`` cannot be a password (the placeholder of the examples), or None."""
    if secret.strip().lower() in PLACEHOLDER_PASSWORDS:
        return (
            f"{secret.strip()!r} is the placeholder of the examples, not a password: generate "
            "one (deploy/zenoh/make-secrets.sh) and give it by password_file"
        )
    return None


class ZenohAuth(_Model):
    """Zenoh user/password authentication (zenoh's ``transport/auth/usrpwd``)."""

    user: str | None = Field(default=None, description="the name this gateway logs in with")
    password: str | None = Field(default=None, description="its password (or password_file)")
    password_file: str | None = Field(default=None, description="file holding the password")
    dictionary_file: str | None = Field(
        default=None, description="user:password lines: who may connect to this gateway (peer)"
    )

    @field_validator("password")
    @classmethod
    def _not_a_placeholder(cls, v: str | None) -> str | None:
        why = placeholder_problem(v) if v is not None else None
        if why:
            raise ValueError(why)
        return v

    @model_validator(mode="after")
    def _pairs(self) -> ZenohAuth:
        if self.password is not None and self.password_file is not None:
            raise ValueError("password and password_file: give one, not both")
        has_pw = self.password is not None or self.password_file is not None
        if self.user is None and has_pw:
            raise ValueError("user is missing (a password needs a user)")
        if self.user is not None and not has_pw:
            raise ValueError(f"user {self.user!r} has no password (password or password_file)")
        if self.user is None and self.dictionary_file is None:
            raise ValueError("empty: give user and password, or dictionary_file, or remove auth")
        return self


class ZenohHistory(_Model):
    """What the advanced publishers keep for subscribers that missed samples (router down, WAN
    link lost, late joiners): samples per key, and the heartbeat that lets them see a miss."""

    events: int = Field(default=1000, ge=0, le=1_000_000, description="per state/EMCY key; 0 = none")
    values: int = Field(default=1, ge=0, le=10_000, description="per value key; 0 = none")
    heartbeat_ms: int = Field(default=500, ge=0, le=60_000, description="0 = no miss detection")


class ZenohSection(_Model):
    enabled: bool = True
    mode: Literal["peer", "client"] = "peer"
    listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    connect: list[str] = Field(default_factory=list)
    prefix: str | None = None
    multicast_scouting: bool = False
    #: change / every: a sample per signal on its value key; pdo: a sample per received PDO
    #: with all its signals on ``<node>/tpdo/<n>`` (a signal's own publish still applies)
    publish: Literal["change", "every", "pdo"] = "change"
    batch_ms: float = Field(
        default=1.0,
        ge=0,
        le=100,
        description="values of frames received within this window go out together (0 = per burst)",
    )
    raw_pdo: bool = False
    tls: ZenohTls | None = None
    writes: bool = Field(default=False, description="off: every set, SDO download, NMT refused")
    write_allow: list[ZenohWriteRule] = Field(
        default_factory=list, description="with writes on: only what a rule allows; empty = all"
    )
    reads: Literal["catalog", "all"] = Field(
        default="catalog",
        description="SDO uploads by query: catalog = only the objects the catalogue lists, all = any",
    )
    auth: ZenohAuth | None = None
    access_control: dict[str, Any] | None = Field(
        default=None, description="zenoh's access_control section (rules, subjects, policies)"
    )
    history: ZenohHistory = Field(default_factory=ZenohHistory)
    refuse_duplicate_prefix: bool = Field(
        default=True,
        description="keep Zenoh closed (and retry) while another announces a gateway under our prefix",
    )
    json5: dict[str, Any] = Field(
        default_factory=dict, description="raw zenoh config keys, e.g. {'transport/link/tls/..': ..}"
    )

    @model_validator(mode="after")
    def _writes(self) -> ZenohSection:
        if self.write_allow and not self.writes:
            raise ValueError("write_allow has no effect while writes is off: set writes: on")
        if self.prefix is not None:
            why = keyexpr.problem(self.prefix.rstrip("/"))
            if why or "*" in self.prefix or "$" in self.prefix:
                raise ValueError(f"prefix: {why or 'no wildcards in a prefix'}")
        return self

    def key_prefix(self, gateway_name: str) -> str:
        return self.prefix if self.prefix else f"canopen/{gateway_name}"
