"""Engineering scaling, the one definition: engineering value = raw x scale + offset, with the
node's overrides of unit, scale and offset (``nodes[].signals.<name>``) over the profile's.

Zenoh publishes and takes engineering values, the Modbus register map shows engineering ranges
and serves ``as_float`` points as float32 engineering values, the web console shows and takes
them: all through these functions.

Imports: config (SignalOverride), profiles.schema (Signal). Nothing else of the gateway.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gateway.config import SignalOverride
from gateway.profiles.schema import Signal


@dataclass(frozen=True)
class Scaling:
    """Engineering view of a signal on this gateway: profile values with the node's overrides."""

    unit: str
    scale: float
    offset: float

    @classmethod
    def of(cls, sig: Signal, ov: SignalOverride | None) -> Scaling:
        return cls(
            ov.unit if ov is not None and ov.unit is not None else sig.unit,
            ov.scale if ov is not None and ov.scale is not None else sig.scale,
            ov.offset if ov is not None and ov.offset is not None else sig.offset,
        )

    @property
    def identity(self) -> bool:
        return self.scale == 1.0 and not self.offset


def scaled(raw: float, scale: float, offset: float) -> float:
    """Raw device value -> engineering value (no rounding)."""
    return raw * scale + offset


def unscaled_step(eng: float, scale: float, offset: float) -> int:
    """Engineering value -> the nearest raw integer step (0 when the scale is 0). NaN and
    infinity raise ValueError / OverflowError."""
    return round((eng - offset) / scale) if scale else 0


def engineering(sig: Signal, raw: Any, sc: Scaling) -> Any:
    """Raw device value -> JSON-able engineering value."""
    if raw is None:
        return None
    if isinstance(raw, (bytes, bytearray)):
        if sig.type == "string":
            return bytes(raw).rstrip(b"\0").decode("ascii", errors="replace")
        return bytes(raw).hex()
    if sc.identity or isinstance(raw, str):
        return raw
    return round(scaled(raw, sc.scale, sc.offset), 9)


def to_raw(sig: Signal, value: Any, sc: Scaling) -> Any:
    """Engineering value from a client -> raw device value (range checks are the command
    service's). Integer types are rounded to the nearest step."""
    if sc.identity or sig.type in ("string", "bytes") or isinstance(value, (str, bool)):
        return value
    if not isinstance(value, (int, float)):
        raise ValueError(f"{sig.name}: expected a number, got {value!r}")
    if sc.scale == 0:
        raise ValueError(f"{sig.name}: scale is 0, write {{'raw': value}} instead")
    raw = (value - sc.offset) / sc.scale
    return raw if sig.type == "float32" else round(raw)


def bits_of(sig: Signal, raw: Any) -> dict[str, Any] | None:
    """The named bit fields of a word (a field wider than one bit as its number)."""
    if not sig.bits or not isinstance(raw, int):
        return None
    return {
        b.name: (raw >> b.bit) & ((1 << b.width) - 1) if b.width > 1 else bool(raw >> b.bit & 1)
        for b in sig.bits
    }
