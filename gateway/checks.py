"""Protocol feasibility checks of a config (``canopen-gateway check`` and config loading).

Rules a config must meet that span several sections, e.g. an AP05 external heartbeat
(AP05 manual 5.5.4, 5F09h) that the gateway's SYNC period or RPDO keep-alive cannot feed in time.
Pure: imports config, profiles and the supervision rules only.
"""

from __future__ import annotations

from gateway.config import Config
from gateway.profiles import load_profile


def protocol_problems(cfg: Config) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for i, n in enumerate(cfg.nodes):
        key = f"nodes[{i}]"
        lp = load_profile(n.profile, cfg.base_dir)
        if n.external_heartbeat is not None:
            if "external_heartbeat" not in lp.profile.features:
                out.append(
                    (f"{key}.external_heartbeat", f"profile {n.profile} has no external heartbeat")
                )
                continue
            eh = n.external_heartbeat
            if eh.source == "sync":
                period = cfg.master.sync_period_ms
                if not period:
                    out.append(
                        (
                            f"{key}.external_heartbeat.source",
                            "source sync needs master.sync_period_ms > 0",
                        )
                    )
                elif period >= eh.interval_ms:
                    out.append(
                        (
                            "master.sync_period_ms",
                            f"SYNC every {period:g} ms cannot feed {n.name}'s external heartbeat "
                            f"of {eh.interval_ms} ms; use a SYNC period below {eh.interval_ms} ms",
                        )
                    )
            else:
                keep = eh.keepalive_ms or max(1, eh.interval_ms // 2)
                if keep >= eh.interval_ms:
                    out.append(
                        (
                            f"{key}.external_heartbeat.keepalive_ms",
                            f"keep-alive every {keep} ms cannot feed an external heartbeat of "
                            f"{eh.interval_ms} ms; must be below {eh.interval_ms} ms",
                        )
                    )
        sup = n.supervision or lp.profile.boot.supervision
        if sup == "guarding":
            gt = n.guard_time_ms if n.guard_time_ms is not None else lp.profile.boot.guard_time_ms
            ltf = (
                n.life_time_factor
                if n.life_time_factor is not None
                else lp.profile.boot.life_time_factor
            )
            if not gt or not ltf:
                out.append(
                    (f"{key}.guard_time_ms", "node guarding needs guard_time_ms and life_time_factor > 0")
                )
    return out
