"""What the device knowledge reads of one configured node: one frozen record, config-free.

``NodeSetup`` is the node's choice of device (profile, EDS or DCF), its PDO layout settings
(``tpdo:``/``rpdo:``, ``pdo_variant``), its own SDO writes, its supervision and its external
heartbeat, as the node's configuration gives them (``None``: the profile's, else the EDS's).
The config builds it in one place (``canopen_gateway.config.NodeConfig.setup``); the profile loader
(``load_node_profile``), the mapping check (``node_verifies_mapping``) and the boot-step builder
(``canopen_gateway.device.boot_steps``) read it and nothing of the config. A test builds one directly.

Imports: canopen.objref. No I/O.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from canopen_gateway.canopen.objref import ObjRef


@dataclass(frozen=True)
class PdoSetup:
    """One PDO the node's ``tpdo:``/``rpdo:`` settings name (``None``: as the layout has it)."""

    enabled: bool = True
    cob_id: int | None = None
    transmission: int | None = None
    event_timer_ms: int | None = None
    inhibit_ms: float | None = None
    sync_start: int | None = None
    #: the entries as written in the config (``"6000h:01"``, ``"6401h:01/16"``, dummies)
    mapping: tuple[str, ...] | None = None


@dataclass(frozen=True)
class SdoSetup:
    """One SDO download of the node's own ``sdo:`` list, applied after the profile's."""

    object: ObjRef
    value: int | float | str
    type: str | None = None
    note: str = ""


@dataclass(frozen=True)
class ExternalHeartbeatSetup:
    """The device's external heartbeat (AP05 manual 5.5.4, 5F09h): interval and source."""

    interval_ms: int
    source: str = "rpdo"  # "rpdo" | "sync"


@dataclass(frozen=True)
class NodeSetup:
    """One node as the device knowledge reads it (see the module docstring)."""

    node_id: int
    profile: str | None = None
    eds: str | None = None
    pdo_variant: int | None = None
    configure: bool = True
    tpdo: Mapping[int, PdoSetup] = field(default_factory=dict)
    rpdo: Mapping[int, PdoSetup] = field(default_factory=dict)
    sdo: tuple[SdoSetup, ...] = ()
    #: the node's own supervision choice and times (``None``: the profile's boot defaults)
    supervision: str | None = None
    heartbeat_ms: int | None = None
    guard_time_ms: int | None = None
    life_time_factor: int | None = None
    external_heartbeat: ExternalHeartbeatSetup | None = None
    #: read the mapping objects back before NMT start (``None``: the default of the device)
    verify_mapping: bool | None = None

    @property
    def eds_only(self) -> bool:
        """No profile: the node is described by its EDS alone."""
        return not self.profile

    def cache_key(self, base_dir: object) -> str:
        """The text that identifies this setup under ``base_dir`` (the loader's cache key)."""
        return f"{self!r}@{base_dir}"
