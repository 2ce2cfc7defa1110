"""Zenoh bridge: publishes the process image, liveliness per node, events, and answers queries.

Values are published from the bus reader thread (zenoh puts are thread-safe and, with
congestion control DROP for values, never block the reader); events (state, EMCY) go out from
the event loop with congestion control BLOCK and a higher priority, so they are never dropped.
Query callbacks run on zenoh threads: they only hand the query to the event loop, where the
command service answers it and the query is finalised.

Imports: zenoh, commands, errors, image, zenoh_bridge.keys, modbus.regmap is NOT imported
(the catalogue gets Modbus addresses through a plain function passed in by the app).
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from typing import Any

import zenoh

from gateway.commands import CommandService
from gateway.config import Config
from gateway.errors import GatewayError, SdoAbort
from gateway.image import LinkState, NodeImage, ProcessImage, Quality
from gateway.objref import ObjRef
from gateway.profiles.schema import Signal
from gateway.zenoh_bridge.keys import (
    GATEWAY_TOKEN,
    alive_key,
    emcy_key,
    prefix_of,
    state_key,
    value_key,
)

log = logging.getLogger("gateway.zenoh")

QUALITY_TEXT = {Quality.GOOD: "good", Quality.STALE: "stale", Quality.BAD: "bad"}


def zenoh_config(cfg: Config) -> zenoh.Config:
    z = cfg.zenoh
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(z.mode))
    conf.insert_json5("listen/endpoints", json.dumps(z.listen))
    conf.insert_json5("connect/endpoints", json.dumps(z.connect))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(z.multicast_scouting))
    if z.mode == "client":
        conf.insert_json5("connect/exit_on_failure", "false")
    for key, value in z.json5.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def engineering(sig: Signal, raw: Any, scale: float, offset: float) -> Any:
    if isinstance(raw, (bytes, bytearray)):
        if sig.type == "string":
            return bytes(raw).rstrip(b"\0").decode("ascii", errors="replace")
        return bytes(raw).hex()
    if scale != 1.0 or offset:
        return raw * scale + offset
    return raw


class _SignalPub:
    __slots__ = ("sig", "pub", "unit", "scale", "offset", "deadband", "min_interval", "mode",
                 "last_value", "last_time")  # fmt: skip

    def __init__(self, sig: Signal, pub: Any, unit: str, scale: float, offset: float,
                 deadband: float, min_interval: float, mode: str):  # fmt: skip
        self.sig, self.pub, self.unit = sig, pub, unit
        self.scale, self.offset = scale, offset
        self.deadband, self.min_interval, self.mode = deadband, min_interval, mode
        self.last_value: Any = None
        self.last_time = 0.0


class ZenohBridge:
    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        commands: CommandService,
        catalog_fn: Callable[[], dict[str, Any]] | None = None,
    ):
        self.cfg = cfg
        self.image = image
        self.commands = commands
        self.catalog_fn = catalog_fn
        self.prefix = prefix_of(cfg)
        self.session: zenoh.Session | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.pubs: dict[tuple[str, str], _SignalPub] = {}
        self.event_pubs: dict[str, Any] = {}
        self.tokens: dict[str, Any] = {}
        self.queryable: Any = None
        self.publications = 0
        self.up = False

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        self.loop = asyncio.get_running_loop()
        conf = zenoh_config(self.cfg)
        self.session = await asyncio.to_thread(zenoh.open, conf)
        s = self.session
        for name in self.image.nodes:
            rt = self.commands.node(name)
            ncfg = rt.cfg
            for sig in rt.lp.profile.signals:
                if sig.transport != "pdo":
                    continue
                ov = ncfg.signals.get(sig.name)
                mode = (ov.publish if ov and ov.publish else None) or self.cfg.zenoh.publish
                if mode == "off":
                    continue
                pub = s.declare_publisher(
                    value_key(self.prefix, name, sig.name),
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.DROP,
                )
                self.pubs[(name, sig.name)] = _SignalPub(
                    sig,
                    pub,
                    ov.unit if ov and ov.unit is not None else sig.unit,
                    ov.scale if ov and ov.scale is not None else sig.scale,
                    ov.offset if ov and ov.offset is not None else sig.offset,
                    ov.deadband if ov else 0.0,
                    1.0 / ov.max_rate_hz if ov and ov.max_rate_hz else 0.0,
                    mode,
                )
            for kind, key in (("state", state_key), ("emcy", emcy_key)):
                self.event_pubs[f"{name}/{kind}"] = s.declare_publisher(
                    key(self.prefix, name),
                    encoding=zenoh.Encoding.APPLICATION_JSON,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.INTERACTIVE_HIGH,
                )
        self.tokens[GATEWAY_TOKEN] = s.liveliness().declare_token(
            alive_key(self.prefix, GATEWAY_TOKEN)
        )
        self.queryable = s.declare_queryable(f"{self.prefix}/**", self._on_query)
        self.image.value_listeners.append(self._on_values)
        self.image.health_listeners.append(self._on_health)
        for node in self.image.nodes.values():
            self._sync_token(node)
        self.up = True

    async def stop(self) -> None:
        self.up = False
        if self._on_values in self.image.value_listeners:
            self.image.value_listeners.remove(self._on_values)
        if self._on_health in self.image.health_listeners:
            self.image.health_listeners.remove(self._on_health)
        s, self.session = self.session, None
        if s is not None:
            await asyncio.to_thread(s.close)

    # ------------------------------------------------------------------ publishing
    def _payload(self, node: NodeImage, sp: _SignalPub, raw: Any, ts: float, seq: int) -> dict[str, Any]:
        sig = node.signals[sp.sig.name]
        d: dict[str, Any] = {
            "value": engineering(sp.sig, raw, sp.scale, sp.offset),
            "unit": sp.unit,
            "ts": ts,
            "quality": QUALITY_TEXT[node.quality(sig)],
            "seq": seq,
        }
        if sp.sig.bits and isinstance(raw, int):
            d["bits"] = {
                b.name: (raw >> b.bit) & ((1 << b.width) - 1) if b.width > 1 else bool(raw >> b.bit & 1)
                for b in sp.sig.bits
            }
        return d

    def _on_values(self, node: NodeImage, names: tuple[str, ...], ts: float) -> None:
        """Called on the bus reader thread for every decoded PDO."""
        s = self.session
        if s is None:
            return
        now = time.monotonic()
        pubs = self.pubs
        for name in names:
            sp = pubs.get((node.name, name))
            if sp is None:
                continue
            sig = node.signals[name]
            raw = sig.value
            if sp.mode == "change":
                last = sp.last_value
                if last is not None:
                    if raw == last:
                        continue
                    if sp.deadband and isinstance(raw, (int, float)):
                        if abs(raw - last) * abs(sp.scale) < sp.deadband:
                            continue
                if sp.min_interval and now - sp.last_time < sp.min_interval:
                    continue
            sp.last_value = raw
            sp.last_time = now
            try:
                sp.pub.put(
                    json.dumps(self._payload(node, sp, raw, ts, sig.seq)),
                    timestamp=s.new_timestamp(),
                )
                self.publications += 1
            except zenoh.ZError:
                pass

    def _state_payload(self, node: NodeImage) -> dict[str, Any]:
        h = node.health
        return {
            "node": node.name,
            "node_id": node.node_id,
            "nmt_state": h.nmt_state.name.lower(),
            "alive": h.alive,
            "operational": node.operational(),
            "lifecycle": h.lifecycle,
            "supervision": h.supervision,
            "link": h.link.name.lower(),
            "loss_count": h.loss_count,
            "boot_count": h.boot_count,
            "current_errors": [f"0x{c:04X}" for c in h.current_errors],
            "last_error": h.last_error,
            "ts": time.time(),
        }

    def _on_health(self, node: NodeImage, what: str) -> None:
        """Called on the event loop when a node's health changes or an EMCY arrives."""
        s = self.session
        if s is None:
            return
        try:
            if what == "emcy" and node.health.last_emcy is not None:
                e = node.health.last_emcy
                payload = {
                    "node": node.name,
                    "code": f"0x{e.code:04X}",
                    "register": e.register,
                    "manufacturer": e.manufacturer.hex(),
                    "text": e.text,
                    "ts": e.timestamp,
                    "count": node.health.emcy_count,
                }
                self.event_pubs[f"{node.name}/emcy"].put(json.dumps(payload), timestamp=s.new_timestamp())
            else:
                self.event_pubs[f"{node.name}/state"].put(
                    json.dumps(self._state_payload(node)), timestamp=s.new_timestamp()
                )
            self.publications += 1
        except zenoh.ZError as exc:
            log.warning("zenoh event publication failed: %s", exc)
        self._sync_token(node)
        if what == "state":
            # republish values with their new quality on the next change
            for (n, _), sp in self.pubs.items():
                if n == node.name:
                    sp.last_value = None

    def _sync_token(self, node: NodeImage) -> None:
        s = self.session
        if s is None:
            return
        alive = node.health.alive and node.health.link != LinkState.FAULT
        tok = self.tokens.get(node.name)
        if alive and tok is None:
            self.tokens[node.name] = s.liveliness().declare_token(alive_key(self.prefix, node.name))
        elif not alive and tok is not None:
            del self.tokens[node.name]
            try:
                tok.undeclare()
            except zenoh.ZError:
                pass

    # ------------------------------------------------------------------ queries
    def _on_query(self, query: zenoh.Query) -> None:
        """Zenoh thread: hand over to the event loop; never block here."""
        loop = self.loop
        if loop is None or loop.is_closed():
            query.drop()
            return
        try:
            loop.call_soon_threadsafe(lambda: asyncio.ensure_future(self._answer(query)))
        except RuntimeError:
            query.drop()

    async def _answer(self, query: zenoh.Query) -> None:
        key = str(query.key_expr)
        try:
            payload = query.payload.to_bytes() if query.payload is not None else None
            result = await self._dispatch(key, payload)
            query.reply(key, json.dumps(result), encoding=zenoh.Encoding.APPLICATION_JSON)
        except GatewayError as exc:
            query.reply_err(json.dumps(error_json(exc)), encoding=zenoh.Encoding.APPLICATION_JSON)
        except (ValueError, KeyError, TypeError) as exc:
            query.reply_err(json.dumps({"error": "bad_request", "message": str(exc)}))
        except Exception as exc:  # noqa: BLE001 - nothing a client sends may crash the gateway
            log.exception("zenoh query %s failed", key)
            query.reply_err(json.dumps({"error": "internal", "message": str(exc)}))
        finally:
            query.drop()

    async def _dispatch(self, key: str, payload: bytes | None) -> Any:
        if not key.startswith(self.prefix + "/"):
            raise ValueError(f"key {key} is not under {self.prefix}")
        parts = key[len(self.prefix) + 1 :].split("/")
        if parts == ["catalog"]:
            return self.catalog_fn() if self.catalog_fn else {}
        if parts[0] == "alive":
            raise ValueError("alive/* are liveliness tokens; use a liveliness query")
        node = parts[0]
        rt = self.commands.node(node)
        rest = parts[1:]
        if rest == ["snapshot"]:
            return self.snapshot(rt.image)
        if rest == ["state"]:
            return self._state_payload(rt.image)
        if rest == ["nmt"]:
            cmd = _text(payload, "NMT command: start, stop, preop, reset or reset-comm")
            self.commands.nmt(node, cmd.strip('"'))
            return {"ok": True, "node": node, "nmt": cmd.strip('"')}
        if len(rest) == 3 and rest[0] == "sdo":
            obj = ObjRef(int(rest[1], 16), int(rest[2], 16))
            if payload:
                body = _json(payload, 'a JSON value, or {"value": v, "type": "uint16"}')
                value, typ = (body.get("value"), body.get("type")) if isinstance(body, dict) else (body, None)
                await self.commands.sdo_write(node, obj, value, typ)
                return {"ok": True, "object": str(obj)}
            typ = None
            value = await self.commands.sdo_read(node, obj, typ)
            if isinstance(value, (bytes, bytearray)):
                value = bytes(value).hex()
            return {"object": str(obj), "value": value}
        if rest == ["set"]:
            body = _json(payload, 'a JSON object {"signal": value, ...}')
            if not isinstance(body, dict) or not body:
                raise ValueError('expected a JSON object {"signal": value, ...}')
            await self.commands.write_signals(node, body)
            return {"ok": True, "written": sorted(body)}
        if len(rest) == 2 and rest[0] == "set":
            body = _json(payload, 'a JSON value or {"value": v} or {"bits": {"name": true}}')
            sig = self.commands.signal(rt, rest[1])
            if isinstance(body, dict) and "bits" in body:
                bits = {}
                names = {b.name: b.bit for b in sig.bits}
                for bname, on in body["bits"].items():
                    if bname not in names:
                        raise ValueError(f"{rest[1]} has no bit {bname!r}; bits: {sorted(names)}")
                    bits[names[bname]] = bool(on)
                await self.commands.write_bits(node, rest[1], bits)
            else:
                value = body.get("value") if isinstance(body, dict) else body
                await self.commands.write_signal(node, rest[1], value)
            return {"ok": True, "signal": rest[1]}
        raise ValueError(
            f"unknown key {key}; expected {self.prefix}/<node>/(snapshot|state|nmt|set|set/<signal>|"
            "sdo/<index hex>/<sub hex>) or catalog"
        )

    def snapshot(self, node: NodeImage) -> dict[str, Any]:
        rt = self.commands.node(node.name)
        values = {}
        for sig in rt.lp.profile.signals:
            if sig.transport != "pdo":
                continue
            sv = node.signals[sig.name]
            sp = self.pubs.get((node.name, sig.name))
            scale = sp.scale if sp else sig.scale
            offset = sp.offset if sp else sig.offset
            values[sig.name] = {
                "value": engineering(sig, sv.value, scale, offset) if sv.seq else None,
                "unit": sp.unit if sp else sig.unit,
                "ts": sv.timestamp,
                "quality": QUALITY_TEXT[node.quality(sv)],
                "seq": sv.seq,
            }
        return {"node": node.name, "state": self._state_payload(node), "values": values}


def error_json(exc: GatewayError) -> dict[str, Any]:
    d: dict[str, Any] = {"error": exc.kind, "message": str(exc)}
    if isinstance(exc, SdoAbort):
        d["code"] = f"0x{exc.code:08X}"
        d["text"] = exc.text
    return d


def _json(payload: bytes | None, expected: str) -> Any:
    if not payload:
        raise ValueError(f"payload missing: expected {expected}")
    try:
        return json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise ValueError(f"payload is not JSON: expected {expected}") from None


def _text(payload: bytes | None, expected: str) -> str:
    if not payload:
        raise ValueError(f"payload missing: expected {expected}")
    try:
        return payload.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise ValueError(f"payload is not text: expected {expected}") from None
