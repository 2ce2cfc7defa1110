"""The bus's output vocabulary: what a node machine (``bus.node.node.Node``), its SDO channel
(``bus.sdo``) and their parts return to the driver, the outputs of every event. Here, beside both
packages, so neither imports the other for it.

Imports: pdo.refresh (the plan's record, re-exported) and the standard library. No I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from canopen_gateway.pdo.refresh import Refresh


@dataclass(frozen=True)
class Send:
    """Action: send this frame. ``rpdo`` marks process data sent (for the raw-PDO listeners)."""

    cob_id: int
    data: bytes = b""
    rtr: bool = False
    dlc: int | None = None
    rpdo: bool = False


@dataclass(frozen=True)
class SdoDone:
    """Result of a ``request_sdo``: ``data`` (upload bytes, b"" for a download) or an error."""

    token: int
    data: bytes | None
    abort_code: int | None = None
    timed_out: bool = False
    by_server: bool = False


@dataclass(frozen=True)
class ValuesRead:
    """Values for the process image that did not come in a TPDO: read by SDO (refresh after
    NMT start), or outputs just sent. Names not in the image are ignored. ``valid_at_s``: the
    latest instant (bus clock) the values are known to have been valid at the device before,
    for a value read by SDO the time its request went out (the device took the value after
    it); the image stamps the values with it, so a TPDO received after the request, and
    handled before the answer, keeps the newer value. None: now."""

    names: tuple[str, ...]
    values: tuple[Any, ...]
    valid_at_s: float | None = None


@dataclass(frozen=True)
class HealthChanged:
    what: str  # "state" | "emcy"


@dataclass(frozen=True)
class Note:
    """A line for the log (the driver writes it)."""

    level: int
    text: str
    kind: Any = None  # set: rate-limited per kind


Output = Send | SdoDone | ValuesRead | HealthChanged | Note

__all__ = ["HealthChanged", "Note", "Output", "Refresh", "SdoDone", "Send", "ValuesRead"]
