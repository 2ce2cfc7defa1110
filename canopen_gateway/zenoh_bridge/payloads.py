"""JSON payloads of the Zenoh bridge (pure: no zenoh import): value samples, node state and
EMCY events, error replies, and the parsing of what clients send in queries.

Values on Zenoh are engineering values (raw x scale + offset, with the node's overrides of unit,
scale and offset; a TIME_OF_DAY as ISO 8601 text, a TIME_DIFFERENCE in milliseconds); writes
take engineering values too and are turned back into raw values here,
or ``{"raw": v}`` passes a raw device value through. Everything a client may send that does not
parse raises ``ValueError`` with a message saying what was expected.

Imports: image, errors, canopen.cia301, northbound.scaling, northbound.summary, profiles.schema, config (types only). Never zenoh, bus/, modbus/.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from typing import Any

from canopen_gateway.canopen.cia301 import NMT_COMMANDS, TIME_TYPES
from canopen_gateway.errors import GatewayError, SdoAbort
from canopen_gateway.image import EmcyRecord, NodeImage, Quality, SignalValue
from canopen_gateway.northbound.scaling import Scaling, bits_of, engineering
from canopen_gateway.northbound.summary import QUALITY_TEXT, summarize
from canopen_gateway.profiles.schema import Signal

#: DS-301 7.2.7.1: EMCY error code 0000h = error reset / no error
EMCY_ERROR_RESET = 0x0000

NMT_EXPECTED = 'an NMT command: start, stop, preop, reset or reset-comm (text, "start" or {"command": "start"})'
SDO_WRITE_EXPECTED = 'a JSON value, {"value": v, "type": "uint16"} or {"hex": "0a0b"}'
SET_EXPECTED = 'a JSON value, {"value": v}, {"raw": v} or {"bits": {"name": true}}'
SET_MANY_EXPECTED = 'a JSON object {"signal": value, ...}'


def value_payload(sig: Signal, sv: SignalValue, quality: Quality, sc: Scaling) -> dict[str, Any]:
    """A value sample: value, unit, source timestamp (s since the epoch), quality, seq."""
    raw = sv.value
    d: dict[str, Any] = {
        "value": engineering(sig, raw, sc) if sv.seq else None,
        "unit": sc.unit,
        "ts": sv.timestamp if sv.seq else None,
        "quality": QUALITY_TEXT[quality],
        "seq": sv.seq,
    }
    if sv.seq:
        add_names(d, sig, raw)
    return d


def add_names(d: dict[str, Any], sig: Signal, raw: Any) -> dict[str, Any]:
    """Add to ``d`` what the profile names in a raw value: ``text`` of an enumeration, ``bits``
    of a word; returns ``d``."""
    text = sig.values.get(raw) if isinstance(raw, int) else None
    if text is not None:
        d["text"] = text
    bits = bits_of(sig, raw)
    if bits is not None:
        d["bits"] = bits
    return d


#: the JSON text of units and signal names, made once per text (the templates below)
_JSON_TEXT: dict[str, str] = {}


def _json_text(text: str) -> str:
    return _JSON_TEXT.get(text) or _JSON_TEXT.setdefault(text, json.dumps(text))


def _plain_number(sig: Signal, sv: SignalValue, sc: Scaling) -> int | float | None:
    """The engineering value of a sample that ``value_payload`` writes as a plain number (a
    received, finite int or float of a signal without bits, value texts or a time type), for
    the templates; None for any other sample."""
    raw = sv.value
    if (
        sv.seq
        and not sig.bits
        and not sig.values
        and type(raw) in (int, float)
        and math.isfinite(raw)
        and sig.type not in TIME_TYPES
    ):
        return raw if sc.identity else round(raw * sc.scale + sc.offset, 9)
    return None


def value_json(sig: Signal, sv: SignalValue, quality: Quality, sc: Scaling) -> str:
    """``json.dumps(value_payload(...))``, with a template for plain numbers (the hot path:
    about 2 us instead of 6 us per sample); the same text either way."""
    value = _plain_number(sig, sv, sc)
    if value is not None and isinstance(sv.timestamp, float):
        return (
            f'{{"value": {value!r}, "unit": {_json_text(sc.unit)}, "ts": {sv.timestamp!r}, '
            f'"quality": "{QUALITY_TEXT[quality]}", "seq": {sv.seq}}}'
        )
    return json.dumps(value_payload(sig, sv, quality, sc))


def pdo_json(
    entries: list[tuple[Signal, SignalValue, Quality, Scaling]], ts: float, seq: int
) -> str:
    """One received PDO with all its signals (``publish: pdo``): the source time and frame
    counter of the record, then per signal what a value sample says of it (value, unit,
    quality; bits and text where the signal has them)."""
    parts = []
    for sig, sv, quality, sc in entries:
        name = _json_text(sig.name)
        value = _plain_number(sig, sv, sc)
        if value is not None:
            parts.append(
                f'{name}: {{"value": {value!r}, "unit": {_json_text(sc.unit)}, '
                f'"quality": "{QUALITY_TEXT[quality]}"}}'
            )
        else:
            d = value_payload(sig, sv, quality, sc)
            del d["ts"], d["seq"]
            parts.append(f"{name}: {json.dumps(d)}")
    return f'{{"ts": {json.dumps(ts)}, "seq": {seq}, "signals": {{{", ".join(parts)}}}}}'


def state_payload(node: NodeImage, now_s: float | None = None) -> dict[str, Any]:
    """The health of a node, published on ``<node>/state`` when it changes."""
    s = summarize(node)
    age = s.data_age_s
    return {
        "node": s.name,
        "node_id": s.node_id,
        "network": node.network,
        "nmt_state": s.nmt_state.name.lower(),
        "alive": s.alive,
        "operational": s.operational,
        "lifecycle": s.lifecycle,
        "supervision": s.supervision,
        "link": s.link.name.lower(),
        "loss_count": s.loss_count,
        "boot_count": s.boot_count,
        "emcy_count": s.emcy_count,
        "current_errors": [f"0x{c:04X}" for c in s.current_errors],
        "last_error": s.last_error,
        "outputs": s.outputs,
        "data_age_s": None if age is None else round(age, 3),
        "ts": time.time() if now_s is None else now_s,
    }


def state_fingerprint(d: dict[str, Any]) -> tuple[Any, ...]:
    """What makes two state payloads different events (not the time, not the data age)."""
    return tuple(
        (k, tuple(v) if isinstance(v, list) else v)
        for k, v in d.items()
        if k not in ("ts", "data_age_s")
    )


def emcy_payload(node: NodeImage, rec: EmcyRecord, count: int) -> dict[str, Any]:
    return {
        "node": node.name,
        "node_id": node.node_id,
        "network": node.network,
        "code": f"0x{rec.code:04X}",
        "register": rec.register,
        "manufacturer": rec.manufacturer.hex(),
        "text": rec.text,
        "reset": rec.code == EMCY_ERROR_RESET,
        "current_errors": [f"0x{c:04X}" for c in node.health.current_errors],
        "ts": rec.timestamp,
        "count": count,
    }


def error_payload(exc: BaseException, key: str) -> dict[str, Any]:
    """The body of a ``reply_err``: a stable ``error`` kind and the words a user needs."""
    if isinstance(exc, GatewayError):
        d: dict[str, Any] = {"error": exc.kind, "message": str(exc), "key": key}
        if isinstance(exc, SdoAbort):
            d["code"] = f"0x{exc.code:08X}"
            d["text"] = exc.text
        return d
    if isinstance(exc, (ValueError, KeyError, TypeError)):
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        return {"error": "bad_request", "message": str(msg), "key": key}
    return {"error": "internal", "message": f"{type(exc).__name__}: {exc}", "key": key}


# --------------------------------------------------------------------------- parsing requests


def json_body(payload: bytes | None, expected: str) -> Any:
    if not payload:
        raise ValueError(f"payload missing: expected {expected}")
    try:
        return json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ValueError(f"payload is not JSON: expected {expected}") from None


def nmt_command(payload: bytes | None) -> str:
    if not payload:
        raise ValueError(f"payload missing: expected {NMT_EXPECTED}")
    try:
        text = payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise ValueError(f"payload is not text: expected {NMT_EXPECTED}") from None
    try:
        body = json.loads(text)
    except json.JSONDecodeError:
        body = text
    if isinstance(body, dict):
        body = body.get("command")
    if not isinstance(body, str) or not body:
        raise ValueError(f"expected {NMT_EXPECTED}")
    if body not in NMT_COMMANDS:
        raise ValueError(f"unknown NMT command {body!r}: expected {NMT_EXPECTED}")
    return body


def sdo_write_body(payload: bytes | None) -> tuple[Any, str | None]:
    """(value, type) of an SDO download; bytes for ``{"hex": ...}``."""
    body = json_body(payload, SDO_WRITE_EXPECTED)
    if isinstance(body, dict):
        if "hex" in body:
            try:
                return bytes.fromhex(str(body["hex"])), None
            except ValueError:
                raise ValueError(f"hex {body['hex']!r} is not hexadecimal bytes") from None
        if "value" not in body:
            raise ValueError(f"expected {SDO_WRITE_EXPECTED}")
        typ = body.get("type")
        if typ is not None and not isinstance(typ, str):
            raise ValueError(f"type must be a name such as uint16; expected {SDO_WRITE_EXPECTED}")
        return body["value"], typ
    if isinstance(body, list) or body is None:
        raise ValueError(f"expected {SDO_WRITE_EXPECTED}")
    return body, None


@dataclass(frozen=True)
class SetRequest:
    """A write of one signal: an engineering value, a raw value, or named bits."""

    value: Any = None
    raw: bool = False
    bits: dict[str, bool] | None = None


def set_body(payload: bytes | None) -> SetRequest:
    body = json_body(payload, SET_EXPECTED)
    if isinstance(body, dict):
        if "bits" in body:
            bits = body["bits"]
            if not isinstance(bits, dict) or not bits:
                raise ValueError('bits: expected {"bit name": true|false, ...}')
            return SetRequest(bits={str(k): bool(v) for k, v in bits.items()})
        if "raw" in body:
            return SetRequest(body["raw"], raw=True)
        if "value" in body:
            return SetRequest(body["value"])
        raise ValueError(f"expected {SET_EXPECTED}")
    if isinstance(body, list) or body is None:
        raise ValueError(f"expected {SET_EXPECTED}")
    return SetRequest(body)


def set_many_body(payload: bytes | None) -> dict[str, Any]:
    body = json_body(payload, SET_MANY_EXPECTED)
    if not isinstance(body, dict) or not body:
        raise ValueError(f"expected {SET_MANY_EXPECTED}")
    return body


def reply_value(value: Any) -> Any:
    """A value read by SDO, JSON-able (bytes as hex)."""
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    return value
