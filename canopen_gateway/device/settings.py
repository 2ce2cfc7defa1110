"""A node's supervision and boot settings, resolved once from the config and its profile.

The one place that decides which value wins (the node's config entry, else the profile's boot
defaults, else the master's): ``check``, the boot-step builder and the master all call
``resolve_node_settings`` and read the same ``NodeSettings``.

Also the external-heartbeat rule (AP05 manual 5.5.4): how often the gateway feeds the
device's watchdog (``external_keepalive_ms``, for the running gateway) and whether that is
often enough (``external_heartbeat_problem``, for ``check``).

Imports: canopen.objref; config and profiles.schema for types only. Nothing northbound, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from canopen_gateway.canopen.objref import ObjRef

if TYPE_CHECKING:
    from canopen_gateway.config import MasterSection, NodeConfig
    from canopen_gateway.profiles.schema import Profile


@dataclass(frozen=True)
class GuardingBit:
    """The guarding-bit check of a node (feature ``guarding_bit``, AP05 manual 5.5.5)."""

    control: ObjRef  # control word object carrying the bit the gateway toggles (5F0Ch)
    control_bit: int  # AP05 manual 5.3.2: bit 8
    status: ObjRef  # status word object echoing it (5F19h)
    status_bit: int  # AP05 manual 5.3.3: bit 8
    period_ms: int  # keep-alive RPDO when the PLC writes nothing
    tolerance_missed: int  # status words (TPDOs) without the echo before a fault
    tolerance_ms: int  # time without the echo before a fault


@dataclass(frozen=True)
class NodeSettings:
    supervision: str  # "heartbeat" | "guarding" | "none"
    heartbeat_ms: int  # producer heartbeat time written to 1017h (0 = off)
    guard_time_ms: int
    life_time_factor: int
    heartbeat_multiple: float  # heartbeat consumer timeout = multiple x heartbeat_ms
    boot_timeout_s: float
    probe_period_s: float  # probe cadence of a node not seen (counted from the loss / start)
    sdo_timeout_s: float
    sdo_retries: int
    guarding_bit: GuardingBit | None
    external_heartbeat_ms: int  # 5F09h:01, 0 = off
    external_heartbeat_source: str  # "rpdo" | "sync"
    keepalive_ms: float  # re-send the last RPDO when none went out for this long (0 = never)
    refresh_on_start: bool  # read change-only TPDO values right after NMT start
    rtr_poll_ms: int | None
    #: SYNC runs on the bus: this gateway produces it or another master does (``master.sync_*``)
    sync_producer: bool = True

    @property
    def life_time_ms(self) -> int:
        return self.guard_time_ms * self.life_time_factor


def external_heartbeat_problem(
    key: str,
    name: str,
    interval_ms: int,
    source: str,
    keepalive_ms: int | None,
    sync_period_ms: float,
) -> tuple[str, str] | None:
    """(config key path, why) when the gateway could not feed the device's watchdog, else None.

    AP05 manual 5.5.4 / 5.7.2.31: with 5F09h:01 = interval > 0 the device drops to
    PRE-OPERATIONAL when no RPDO (5F09h:02 = 0) or no SYNC (= 1) arrives within the interval, so
    the gateway's keep-alive RPDO (``external_keepalive_ms``) or its SYNC must come more often.
    ``key`` is the node's key path (``nodes[i]``), ``name`` its name. The interval's own range
    (0 or 10..65535 ms) is the profile's, checked with the other boot writes.
    """
    if source == "sync":
        if not sync_period_ms:
            return f"{key}.external_heartbeat.source", "source sync needs master.sync_period_ms > 0"
        if sync_period_ms >= interval_ms:
            return (
                "master.sync_period_ms",
                f"SYNC every {sync_period_ms:g} ms cannot feed {name}'s external heartbeat "
                f"of {interval_ms} ms; use a SYNC period below {interval_ms} ms",
            )
        return None
    keep = external_keepalive_ms(interval_ms, keepalive_ms)
    if keep >= interval_ms:
        return (
            f"{key}.external_heartbeat.keepalive_ms",
            f"keep-alive every {keep} ms cannot feed an external heartbeat of "
            f"{interval_ms} ms; must be below {interval_ms} ms",
        )
    return None


def resolve_node_settings(master: MasterSection, node: NodeConfig, profile: Profile) -> NodeSettings:
    """Settings of ``node`` with profile ``profile`` under ``master``. Raises ValueError for a
    combination that cannot run."""
    boot = profile.boot
    supervision = node.supervision or boot.supervision
    hb_ms = node.heartbeat_ms if node.heartbeat_ms is not None else boot.heartbeat_ms
    gt_ms = node.guard_time_ms if node.guard_time_ms is not None else boot.guard_time_ms
    ltf = node.life_time_factor if node.life_time_factor is not None else boot.life_time_factor
    gb = None
    feat = profile.features.get("guarding_bit")
    if feat is not None and node.guarding_bit.enabled:
        gb = GuardingBit(
            control=ObjRef.parse(feat["control"]),
            control_bit=int(feat.get("control_bit", 8)),
            status=ObjRef.parse(feat["status"]),
            status_bit=int(feat.get("status_bit", 8)),
            period_ms=node.guarding_bit.period_ms,
            tolerance_missed=node.guarding_bit.tolerance_missed,
            tolerance_ms=node.guarding_bit.tolerance_ms,
        )
    eh = node.external_heartbeat
    eh_ms = eh.interval_ms if eh is not None else 0
    eh_source = eh.source if eh is not None else "rpdo"
    periods: list[float] = []
    if gb is not None:
        periods.append(float(gb.period_ms))
    if eh is not None and eh.source == "rpdo":
        periods.append(float(external_keepalive_ms(eh.interval_ms, eh.keepalive_ms)))
    return NodeSettings(
        supervision=supervision,
        heartbeat_ms=hb_ms,
        guard_time_ms=gt_ms,
        life_time_factor=ltf,
        heartbeat_multiple=master.heartbeat_timeout_multiple,
        boot_timeout_s=master.boot_timeout_s,
        probe_period_s=master.boot_timeout_s,
        sdo_timeout_s=master.sdo_timeout_s,
        sdo_retries=master.sdo_retries,
        guarding_bit=gb,
        external_heartbeat_ms=eh_ms,
        external_heartbeat_source=eh_source,
        keepalive_ms=min(periods) if periods else 0.0,
        refresh_on_start=node.refresh_on_start,
        rtr_poll_ms=node.rtr_poll_ms,
        sync_producer=bool(master.sync_period_ms or master.sync_external),
    )


def external_keepalive_ms(interval_ms: int, keepalive_ms: int | None) -> int:
    """The RPDO keep-alive period for an external heartbeat: the configured one, else half the
    interval (``external_heartbeat_problem`` checks that it is below the interval)."""
    return keepalive_ms or max(1, interval_ms // 2)
