"""The process's file limit (``RLIMIT_NOFILE``): raised at start toward what the gateway may
need, so that the caps on connections (``modbus.max_connections``, the console's streams) are
reached long before the operating system's limit.

systemd starts services with a soft limit of 1024 unless the unit says otherwise, and
Kubernetes has no setting for it (the container runtime's limits apply). A process may raise
its own soft limit up to its hard limit: ``raise_file_limit`` does, to ``WANTED_FILES`` at
most, and says in one line when even the hard limit leaves less than ``needed`` (the shipped
unit sets ``LimitNOFILE``, the compose files ``ulimits``).

Imports: the standard library only.
"""

from __future__ import annotations

import logging

try:
    import resource
except ImportError:  # pragma: no cover - not on Linux
    resource = None  # type: ignore[assignment]

log = logging.getLogger("gateway")

#: the soft limit the gateway raises itself to when the hard limit allows
WANTED_FILES = 8192


def raise_file_limit(needed: int, wanted: int = WANTED_FILES) -> tuple[int, int] | None:
    """Raise the soft file limit to ``wanted`` (at most the hard limit); returns (soft, hard)
    after, None where there is no such limit. Warns when the result is below ``needed``."""
    if resource is None:
        return None
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
    if soft != resource.RLIM_INFINITY and soft < target:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
            log.debug("file limit raised from %d to %d (hard limit %s)", soft, target, hard)
            soft = target
        except (ValueError, OSError) as exc:
            log.debug("file limit stays %d: %s", soft, exc)
    if soft != resource.RLIM_INFINITY and soft < needed:
        log.warning(
            "the file limit is %d open files, below the %d the configured connection caps may "
            "take: raise it (LimitNOFILE in the systemd unit, ulimit -n, compose ulimits)",
            soft, needed,
        )  # fmt: skip
    return soft, hard
