"""Protocol feasibility checks of a config (``canopen-gateway check`` and config loading).

Rules a config must meet that span several sections, e.g. an AP05 external heartbeat
(AP05 manual 5.5.4, 5F09h) that the gateway's SYNC period or RPDO keep-alive cannot feed in time.
Also: the boot configuration of every configured node can be built (objects in the EDS,
writable, values that fit) and leaves PDO mappings the gateway can decode.
Pure: imports config, profiles, the boot step builder and the PDO codecs (no I/O).
"""

from __future__ import annotations

from gateway.bus.codec import compile_node
from gateway.bus.lifecycle import build_boot_steps
from gateway.config import Config
from gateway.profiles import load_profile


def boot_problems(cfg: Config) -> list[tuple[str, str]]:
    """Boot steps that cannot be built, and PDO mappings they leave that cannot be decoded."""
    out: list[tuple[str, str]] = []
    for i, n in enumerate(cfg.nodes):
        if not n.configure:
            continue
        lp = load_profile(n.profile, cfg.base_dir)
        try:
            steps = build_boot_steps(
                lp, n, n.supervision, n.heartbeat_ms, n.guard_time_ms, n.life_time_factor
            )
            compile_node(lp, n.node_id, n.pdo_variant, [(s.object, s.value) for s in steps])
        except (ValueError, KeyError) as exc:
            out.append((f"nodes[{i}]", str(exc)))
    return out


def protocol_problems(cfg: Config) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = boot_problems(cfg)
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
