"""Engineering scaling, the one definition: engineering value = raw x scale + offset, with the
node's overrides of unit, scale and offset (``nodes[].signals.<name>``) over the profile's.

Zenoh publishes and takes engineering values, the Modbus register map shows engineering ranges
and serves ``as_float`` points as float32 engineering values, the web console shows and takes
them: all through these functions.

The time types are not scaled: their raw value is the CiA 301 48-bit word (``canopen_gateway.canopen.cia301``);
the engineering value of a TIME_OF_DAY is its ISO 8601 text in UTC
(``"2026-11-27T08:30:00.250Z"``), of a TIME_DIFFERENCE its milliseconds; Modbus serves them as
Unix milliseconds / milliseconds (``time_register_ms``).

Imports: canopen.cia301 (time layout), config (SignalOverride), profiles.schema (Signal). Nothing else
of the gateway.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from canopen_gateway.canopen.cia301 import TIME_EPOCH_UNIX_MS, time_ms, time_word
from canopen_gateway.config import SignalOverride
from canopen_gateway.profiles.schema import Signal


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


def time_register_ms(type_: str, word: int) -> int:
    """A time word as Modbus serves it: Unix milliseconds (TIME_OF_DAY), milliseconds
    (TIME_DIFFERENCE)."""
    ms = time_ms(word)
    return ms + TIME_EPOCH_UNIX_MS if type_ == "time_of_day" else ms


def time_word_of_ms(type_: str, ms: int) -> int:
    """The inverse of ``time_register_ms``; ValueError for a time before 1984-01-01 or beyond
    65535 days."""
    if type_ == "time_of_day":
        if ms < TIME_EPOCH_UNIX_MS:
            raise ValueError(f"{ms} Unix ms is before 1984-01-01, the TIME_OF_DAY epoch")
        ms -= TIME_EPOCH_UNIX_MS
    return time_word(ms)


def time_text(word: int) -> str:
    """A TIME_OF_DAY word as ISO 8601 in UTC, to the millisecond."""
    ms = time_register_ms("time_of_day", word)
    t = datetime.fromtimestamp(ms // 1000, UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%S") + f".{ms % 1000:03d}Z"


def time_of_text(text: str) -> int:
    """The TIME_OF_DAY word of an ISO 8601 time (without a zone: UTC); ValueError otherwise."""
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        raise ValueError(f"{text!r} is not an ISO 8601 time such as 2026-11-27T08:30:00.250Z") from None
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    delta = t - datetime(1970, 1, 1, tzinfo=UTC)
    if delta.microseconds % 1000:
        raise ValueError(f"{text!r}: a TIME_OF_DAY counts whole milliseconds")
    return time_word_of_ms("time_of_day", delta // timedelta(milliseconds=1))


def engineering(sig: Signal, raw: Any, sc: Scaling) -> Any:
    """Raw device value -> JSON-able engineering value."""
    if raw is None:
        return None
    if sig.type == "time_of_day":
        return time_text(int(raw))
    if sig.type == "time_difference":
        return time_ms(int(raw))
    if isinstance(raw, (bytes, bytearray)):
        if sig.type == "string":
            return bytes(raw).rstrip(b"\0").decode("ascii", errors="replace")
        return bytes(raw).hex()
    if sc.identity or isinstance(raw, str):
        return raw
    return round(scaled(raw, sc.scale, sc.offset), 9)


def to_raw(sig: Signal, value: Any, sc: Scaling) -> Any:
    """Engineering value from a client -> raw device value (range checks are the command
    service's). Integer types are rounded to the nearest step; a TIME_OF_DAY is ISO 8601 text,
    a TIME_DIFFERENCE milliseconds."""
    if sig.type == "time_of_day":
        if not isinstance(value, str):
            raise ValueError(f"{sig.name}: expected an ISO 8601 time, got {value!r}")
        return time_of_text(value)
    if sig.type == "time_difference":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (
            isinstance(value, float) and not value.is_integer()
        ):
            raise ValueError(f"{sig.name}: expected whole milliseconds, got {value!r}")
        return time_word_of_ms("time_difference", int(value))
    if sc.identity or sig.type in ("string", "bytes") or isinstance(value, (str, bool)):
        return value
    if not isinstance(value, (int, float)):
        raise ValueError(f"{sig.name}: expected a number, got {value!r}")
    if sc.scale == 0:
        raise ValueError(f"{sig.name}: scale is 0, write {{'raw': value}} instead")
    raw = (value - sc.offset) / sc.scale
    return raw if sig.type in ("float32", "float64") else round(raw)


def bits_of(sig: Signal, raw: Any) -> dict[str, Any] | None:
    """The named bit fields of a word (a field wider than one bit as its number)."""
    if not sig.bits or not isinstance(raw, int):
        return None
    return {
        b.name: (raw >> b.bit) & ((1 << b.width) - 1) if b.width > 1 else bool(raw >> b.bit & 1)
        for b in sig.bits
    }
