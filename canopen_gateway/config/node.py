"""The ``nodes:`` entries of the configuration: one ``NodeConfig`` per device, with its PDO
settings, SDO writes, signal overrides, supervision and outputs, and the rules one entry can
check itself. ``NodeConfig.setup`` is the one place an entry becomes the config-free record the
device knowledge reads (``canopen_gateway.profiles.node_setup.NodeSetup``).

Imports: pydantic, canopen_gateway.canopen.objref, canopen_gateway.profiles.schema, canopen_gateway.profiles.node_setup.
Nothing of bus/, modbus/, zenoh_bridge/, checks.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles.node_setup import (
    ExternalHeartbeatSetup,
    NodeSetup,
    PdoSetup,
    SdoSetup,
)
from canopen_gateway.profiles.schema import HexInt, SignalType


def _obj(v: Any) -> ObjRef:
    return ObjRef.parse(v)


Obj = Annotated[ObjRef, BeforeValidator(_obj)]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SdoWrite(_Model):
    object: Obj
    value: int | float | str
    type: SignalType | None = None


class SignalOverride(_Model):
    address: int | None = Field(default=None, ge=0, le=65535, description="pin a Modbus address")
    unit: str | None = None
    scale: float | None = None
    offset: float | None = None
    word_order: Literal["big", "little"] | None = None
    as_float: bool | None = Field(default=None, description="serve as engineering float32")
    deadband: float = Field(default=0.0, ge=0)
    max_rate_hz: float | None = Field(default=None, gt=0)
    publish: Literal["change", "every", "off"] | None = None


class GuardingBitSettings(_Model):
    """AP05 manual 5.5.5: the gateway toggles control-word bit 8, the device echoes it."""

    enabled: bool = True
    period_ms: int = Field(
        default=500, ge=10, le=60000, description="re-send the last RPDO when none went out for this long"
    )
    tolerance_missed: int = Field(
        default=3,
        ge=1,
        le=1000,
        description="fault after more than this many status words (TPDOs) in a row without the echo",
    )
    tolerance_ms: int = Field(
        default=1000, ge=10, le=600000, description="fault when a toggle is not echoed for this long"
    )


class ExternalHeartbeat(_Model):
    interval_ms: int = Field(ge=1, le=65535)
    source: Literal["rpdo", "sync"] = "rpdo"
    keepalive_ms: int | None = Field(default=None, ge=1, le=65535)


class NodeModbus(_Model):
    unit_id: int | None = Field(default=None, ge=1, le=247)
    serve_stale: bool = False


class PdoSetting(_Model):
    """One PDO of a node (``tpdo:``/``rpdo:``, keyed by PDO number), written at boot with the
    CiA 301 sequence: COB-ID bit 31 set, parameters, mapping sub 0 = 0, entries, sub 0 = n,
    COB-ID valid."""

    enabled: bool = True
    cob_id: HexInt | None = Field(default=None, ge=1, le=0x7FF, description="default: EDS / CiA 301")
    transmission: int | None = Field(default=None, ge=0, le=255, description="transmission type")
    event_timer_ms: int | None = Field(default=None, ge=0, le=65535)
    inhibit_ms: float | None = Field(default=None, ge=0, le=6553.5, description="0.1 ms steps")
    sync_start: int | None = Field(default=None, ge=0, le=240)
    mapping: list[str] | None = Field(
        default=None, description='["0x6000:01", "0x6401:01/16", "0x0005:00" (dummy 8 bit), ...]'
    )


def _pdo_numbers(v: Any) -> Any:
    if isinstance(v, dict):
        out = {}
        for k, val in v.items():
            try:
                n = int(k)
            except (TypeError, ValueError):
                raise ValueError(f"PDO number {k!r} is not a number 1..512") from None
            if not 1 <= n <= 512:
                raise ValueError(f"PDO number {n} is not 1..512")
            out[n] = {} if val is None else val
        return out
    return v


PdoSettings = Annotated[dict[int, PdoSetting], BeforeValidator(_pdo_numbers)]


class NodeConfig(_Model):
    name: str = Field(pattern=r"^[a-z][a-z0-9_\-]*$")
    node_id: int = Field(ge=1, le=127)
    profile: str | None = Field(default=None, description="built-in name or profile .yaml")
    eds: str | None = Field(default=None, description="the device's EDS or DCF (path)")
    tpdo: PdoSettings = Field(default_factory=dict)
    rpdo: PdoSettings = Field(default_factory=dict)
    verify_mapping: bool | None = Field(
        default=None, description="read 1800h../1A00h.. back after configuring (default: EDS-only nodes)"
    )
    identity_check: bool = Field(
        default=True, description="read 1018h:01/02 (:04 for a DCF) at boot and refuse another device"
    )
    supervision: Literal["heartbeat", "guarding", "none"] | None = None
    heartbeat_ms: int | None = Field(default=None, ge=0, le=65535)
    guard_time_ms: int | None = Field(default=None, ge=0, le=65535)
    life_time_factor: int | None = Field(default=None, ge=0, le=255)
    pdo_variant: HexInt | None = None
    rtr_poll_ms: int | None = Field(default=None, ge=1, description="poll TPDOs by RTR")
    configure: bool = True
    sdo: list[SdoWrite] = Field(default_factory=list)
    signals: dict[str, SignalOverride] = Field(default_factory=dict)
    modbus: NodeModbus = Field(default_factory=NodeModbus)
    guarding_bit: GuardingBitSettings = Field(default_factory=GuardingBitSettings)
    external_heartbeat: ExternalHeartbeat | None = None
    stale_after_ms: int | None = Field(default=None, ge=1)
    refresh_on_start: bool = Field(
        default=True,
        description="read TPDOs that send only on change right after NMT start (RTR or SDO)",
    )
    safe_outputs: dict[str, Any] = Field(
        default_factory=dict,
        description="RPDO signal -> raw value written when the Modbus watchdog trips "
        "(overrides the profile's safe_value)",
    )

    @model_validator(mode="after")
    def _device(self) -> NodeConfig:
        if not self.profile and not self.eds:
            raise ValueError("a node needs a profile, an eds (path to the device's EDS/DCF), or both")
        return self

    @property
    def eds_only(self) -> bool:
        return not self.profile

    @property
    def device(self) -> str:
        """What the node is, for listings: the profile name, else the EDS file name."""
        return self.profile or Path(self.eds or "").name

    @property
    def setup(self) -> NodeSetup:
        """What the device knowledge reads of this node: the one place a node's entry becomes
        that record (``canopen_gateway.profiles.node_setup``)."""
        eh = self.external_heartbeat
        return NodeSetup(
            node_id=self.node_id,
            profile=self.profile,
            eds=self.eds,
            pdo_variant=self.pdo_variant,
            configure=self.configure,
            tpdo=_pdo_setups(self.tpdo),
            rpdo=_pdo_setups(self.rpdo),
            sdo=tuple(SdoSetup(w.object, w.value, w.type) for w in self.sdo),
            supervision=self.supervision,
            heartbeat_ms=self.heartbeat_ms,
            guard_time_ms=self.guard_time_ms,
            life_time_factor=self.life_time_factor,
            external_heartbeat=None if eh is None else ExternalHeartbeatSetup(eh.interval_ms, eh.source),
            verify_mapping=self.verify_mapping,
        )


def _pdo_setups(settings: dict[int, PdoSetting]) -> dict[int, PdoSetup]:
    """A node's ``tpdo:`` or ``rpdo:`` entries as the records, by PDO number."""
    return {
        n: PdoSetup(s.enabled, s.cob_id, s.transmission, s.event_timer_ms, s.inhibit_ms,
                    s.sync_start, None if s.mapping is None else tuple(s.mapping))  # fmt: skip
        for n, s in sorted(settings.items())
    }
