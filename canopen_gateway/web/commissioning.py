"""The commissioning operations of the web console: SDO read and write of any object, NMT
commands, set-point writes, LSS inquiry and Fast Scan, a scan of the bus. Present only with ``web.writes: true``; the console
checks the token before calling anything here.

Every device operation goes through the command service, so a write from a browser gets the
same checks as one from Modbus or Zenoh (type, range, writable bits, node operational) and the
same typed errors; here they become an HTTP status and a JSON body with the words a technician
needs (an SDO abort with its code and its DS-301 text).

LSS (CiA 305) goes through the command service to the master's LSS service, on the gateway's
own connection to the bus (no second connection, so it works on every interface), one inquiry
at a time. LSS inquiry switches every LSS slave
(or the one at ``address``) to the LSS configuration state and back to waiting; it does not
change NMT states or node ids. LSS Fast Scan (CiA 305) finds identical unconfigured devices
whose serial numbers are not known, lowest LSS address first, and gives each the next node id;
the same session rules (one at a time, never beside a scan).

Imports: commands, errors, canopen.objref, config, canopen.cia301, profiles.schema, northbound.scaling. Never
bus/, tools/ or python-can.
"""

from __future__ import annotations

import asyncio
import json
import logging
from http import HTTPStatus
from typing import Any

from canopen_gateway.canopen.cia301 import NMT_COMMANDS
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.commands import SDO_TYPES, CommandService
from canopen_gateway.config import Config
from canopen_gateway.errors import (
    BusDown,
    GatewayError,
    LssConflict,
    LssFailed,
    NetworkUnknown,
    NodeNotOperational,
    NodeUnknown,
    NotActive,
    SdoAbort,
    SdoTimeout,
)
from canopen_gateway.northbound.scaling import Scaling, to_raw

log = logging.getLogger("gateway.web")

#: Fast Scan: how long each step waits for 4Fh answers (the CLI waits 50 ms on its own
#: connection; the answers reach the running gateway's event loop through its reader)
FAST_SCAN_WAIT_MS = 100


#: typed errors of the command service -> HTTP status
STATUS_OF: dict[type[GatewayError], HTTPStatus] = {
    NodeUnknown: HTTPStatus.NOT_FOUND,
    NetworkUnknown: HTTPStatus.NOT_FOUND,
    NodeNotOperational: HTTPStatus.CONFLICT,
    BusDown: HTTPStatus.SERVICE_UNAVAILABLE,
    NotActive: HTTPStatus.SERVICE_UNAVAILABLE,  # a pair's standby: the active one does it
    SdoAbort: HTTPStatus.BAD_GATEWAY,  # the device refused
    SdoTimeout: HTTPStatus.GATEWAY_TIMEOUT,  # the device did not answer
    LssFailed: HTTPStatus.GATEWAY_TIMEOUT,  # no LSS slave answered
    LssConflict: HTTPStatus.CONFLICT,  # another LSS session, or the wrong LSS state
}


class BadInput(ValueError):
    """A request body that does not say what is needed; the message says what is expected."""


def error_doc(exc: BaseException) -> tuple[HTTPStatus, dict[str, Any]]:
    if isinstance(exc, GatewayError):
        status = STATUS_OF.get(type(exc), HTTPStatus.BAD_REQUEST)
        doc: dict[str, Any] = {"error": exc.kind, "message": str(exc)}
        if isinstance(exc, SdoAbort):
            doc["abort_code"] = f"0x{exc.code:08X}"
            doc["abort_text"] = exc.text
        return status, doc
    if isinstance(exc, (BadInput, ValueError, TypeError, KeyError)):
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
        return HTTPStatus.BAD_REQUEST, {"error": "bad_request", "message": str(msg)}
    return HTTPStatus.INTERNAL_SERVER_ERROR, {
        "error": "internal",
        "message": f"{type(exc).__name__}: {exc}",
    }


def parse_body(body: bytes) -> dict[str, Any]:
    try:
        doc = json.loads(body.decode("utf-8")) if body else None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BadInput(f"the body is not JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise BadInput('expected a JSON object, e.g. {"node": "wire", ...}')
    return doc


def _text(doc: dict[str, Any], key: str, what: str) -> str:
    v = doc.get(key)
    if not isinstance(v, str) or not v:
        raise BadInput(f"{key}: expected {what}")
    return v


def _obj(doc: dict[str, Any]) -> ObjRef:
    text = _text(doc, "object", "an object address like 0x6004:00")
    try:
        return ObjRef.parse(text)
    except ValueError as exc:
        raise BadInput(f"object: {exc}") from None


def _type(doc: dict[str, Any]) -> str | None:
    t = doc.get("type")
    if t in (None, ""):
        return None
    if t not in SDO_TYPES:
        raise BadInput(f"type: {t!r} is not one of {', '.join(SDO_TYPES)}")
    return str(t)


def _number(doc: dict[str, Any], key: str, low: int, high: int) -> int | None:
    """An optional whole number (JSON number, or text in decimal or 0x hex) within low..high."""
    v = doc.get(key)
    if v in (None, ""):
        return None
    try:
        n = int(v, 0) if isinstance(v, str) else v
    except ValueError:
        n = None
    if isinstance(n, bool) or not isinstance(n, int) or not low <= n <= high:
        raise BadInput(f"{key}: expected a whole number {low}..{high:#x}" if high > 0xFFFF else
                       f"{key}: expected a whole number {low}..{high}")  # fmt: skip
    return n


def shown(value: Any) -> Any:
    """A value as JSON: bytes as hex."""
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex(" ")
    return value


class Commissioning:
    """The write operations, by name: ``await run(op, body)`` -> JSON-able result."""

    OPS = ("sdo-read", "sdo-write", "nmt", "set", "lss-inquire", "lss-fast-scan", "scan")

    def __init__(self, cfg: Config, commands: CommandService, *, lss_timeout_s: float = 0.5):
        self.cfg = cfg
        self.commands = commands
        self.lss_timeout_s = lss_timeout_s
        self._scan_lock = asyncio.Lock()  # one scan at a time

    async def run(self, op: str, body: bytes) -> dict[str, Any]:
        doc = parse_body(body)
        if op == "sdo-read":
            return await self.sdo_read(doc)
        if op == "sdo-write":
            return await self.sdo_write(doc)
        if op == "nmt":
            return await self.nmt(doc)
        if op == "set":
            return await self.set(doc)
        if op == "lss-inquire":
            return await self.lss_inquire(doc)
        if op == "lss-fast-scan":
            return await self.lss_fast_scan(doc)
        if op == "scan":
            return await self.scan(doc)
        raise BadInput(f"unknown operation {op!r}; one of {', '.join(self.OPS)}")

    def _node(self, doc: dict[str, Any]) -> str:
        name = _text(doc, "node", "a node name")
        self.commands.node(name)  # NodeUnknown names the configured nodes
        return name

    async def sdo_read(self, doc: dict[str, Any]) -> dict[str, Any]:
        node, obj, typ = self._node(doc), _obj(doc), _type(doc)
        value = await self.commands.sdo_read(node, obj, typ)
        return {"ok": True, "node": node, "object": str(obj), "value": shown(value)}

    async def sdo_write(self, doc: dict[str, Any]) -> dict[str, Any]:
        node, obj, typ = self._node(doc), _obj(doc), _type(doc)
        if "value" not in doc:
            raise BadInput("value: expected a number or a text (hex bytes with type bytes)")
        value = doc["value"]
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise BadInput(f"value: expected a number or a text, got {value!r}")
        if typ == "bytes" and isinstance(value, str):
            try:
                value = bytes.fromhex(value)
            except ValueError:
                raise BadInput(f"value: {value!r} is not hex bytes (e.g. 0a 0b)") from None
        await self.commands.sdo_write(node, obj, value, typ)
        return {"ok": True, "node": node, "object": str(obj), "value": shown(value)}

    async def nmt(self, doc: dict[str, Any]) -> dict[str, Any]:
        node = _text(doc, "node", "a node name or all")
        if node != "all":
            self.commands.node(node)
        command = _text(doc, "command", "one of " + ", ".join(NMT_COMMANDS))
        await self.commands.nmt(node, command)
        return {"ok": True, "node": node, "command": command}

    async def set(self, doc: dict[str, Any]) -> dict[str, Any]:
        """A signal's value in engineering units (``value``) or raw (``raw``), through the
        command service like a Modbus or Zenoh write."""
        node = self._node(doc)
        name = _text(doc, "signal", "a signal name")
        sig = self.commands.signal(node, name)
        info = self.commands.node(node)
        if "raw" in doc:
            raw = doc["raw"]
        elif "value" in doc:
            ov = info.cfg.signals.get(name) if info.cfg is not None else None
            value = doc["value"]
            if isinstance(value, str) and sig.type not in ("string", "bytes"):
                try:
                    value = float(value) if "." in value or "e" in value.lower() else int(value, 0)
                except ValueError:
                    raise BadInput(f"value: {value!r} is not a number") from None
            raw = to_raw(sig, value, Scaling.of(sig, ov))
        else:
            raise BadInput("value (engineering) or raw: expected one of them")
        await self.commands.write_signal(node, name, raw)
        return {"ok": True, "node": node, "signal": name, "raw": shown(raw)}

    async def lss_inquire(self, doc: dict[str, Any]) -> dict[str, Any]:
        """LSS inquire vendor, product, revision, serial and node id (CiA 305; SGH10 manual
        4.6.3) of the one LSS slave on the bus, or of the slave at ``address``
        (``VENDOR:PRODUCT:REVISION:SERIAL``, switch state selective)."""
        address: tuple[int, int, int, int] | None = None
        text = doc.get("address")
        if text not in (None, ""):
            if not isinstance(text, str):
                raise BadInput("address: expected VENDOR:PRODUCT:REVISION:SERIAL")
            parts = text.replace(" ", "").split(":")
            try:
                numbers = [int(p, 0) for p in parts]
            except ValueError:
                numbers = []
            if len(numbers) == 4 and all(0 <= v < 1 << 32 for v in numbers):
                address = (numbers[0], numbers[1], numbers[2], numbers[3])
            else:
                raise BadInput(
                    f"address: {text!r} is not VENDOR:PRODUCT:REVISION:SERIAL "
                    "(four numbers, e.g. 0x1A2:0x3:0x1:12345)"
                )
        network = self._network(doc)
        if self.commands.lss_busy(network) or self._scan_lock.locked():
            raise LssConflict("another LSS inquiry or a scan is running")
        result = await self.commands.lss_inquire(address, network)
        return {
            "ok": True,
            **{
                item: value if item == "node_id" else f"0x{value if isinstance(value, int) else 0:08X}"
                for item, value in result.items()
            },
        }

    async def lss_fast_scan(self, doc: dict[str, Any]) -> dict[str, Any]:
        """CiA 305 Fast Scan of identical unconfigured devices whose serial numbers are not
        known (``canopen-gateway lss fast-scan``): the LSS address of the one with the lowest;
        with ``node_id`` it is given that node id (``store``: kept over power-off), then the
        next device the next id, ``count`` times. ``vendor``, ``product``, ``revision``: parts
        known in advance (a profile's 1018h), confirmed instead of scanned; ``wait_ms`` per
        step (default ``FAST_SCAN_WAIT_MS``)."""
        vendor, product, revision = (_number(doc, k, 0, 0xFFFFFFFF) for k in ("vendor", "product", "revision"))
        first = _number(doc, "node_id", 1, 127)
        count = _number(doc, "count", 1, 127)
        count = 1 if count is None else count
        wait_ms = _number(doc, "wait_ms", 10, 1000)
        store = doc.get("store", False)
        if not isinstance(store, bool):
            raise BadInput("store: expected true or false")
        if count > 1 and first is None:
            raise BadInput("count: needs node_id, the id the first device found is given")
        if first is not None and first + count - 1 > 127:
            raise BadInput(f"node_id, count: node ids {first}..{first + count - 1} are not within 1..127")
        network = self._network(doc)
        if self.commands.lss_busy(network) or self._scan_lock.locked():
            raise LssConflict("another LSS inquiry, fast scan or a scan is running")
        wait_s = (FAST_SCAN_WAIT_MS if wait_ms is None else wait_ms) / 1000
        result = await self.commands.lss_fast_scan((vendor, product, revision, None), wait_s, first, count, store, network=network)
        found = [{**f, "address": ":".join(f"0x{v:08X}" for v in f["address"])} for f in result["found"]]
        note = "the node ids apply at the next NMT reset communication or power-on" if first is not None else (
            "no node id given: the address can be used in the LSS inquiry")  # fmt: skip
        return {"ok": True, "network": self.commands.network(network).name, "found": found,
                "frames": result["frames"], "failed": result["failed"], "note": note}  # fmt: skip

    async def scan(self, doc: dict[str, Any]) -> dict[str, Any]:
        """Which node ids are on the bus (``canopen-gateway scan --active``): through the
        command service, on the gateway's own connection, one scan at a time and not while an
        LSS inquiry runs (nor an inquiry while a scan runs); of the bus of ``network`` (the
        first by default)."""
        network = self._network(doc)
        if self._scan_lock.locked() or self.commands.lss_busy(network):
            raise LssConflict("a scan or an LSS inquiry is running")
        async with self._scan_lock:
            result = await self.commands.scan_bus(network=network)
        return {"ok": True, "network": self.commands.network(network).name, **result}

    def _network(self, doc: dict[str, Any]) -> str | None:
        """The CAN network an LSS inquiry or a scan works on (``network``; None: the first);
        an unknown name is answered 404 naming the networks."""
        name = doc.get("network") or None
        if name is not None:
            self.commands.network(str(name))  # NetworkUnknown names the networks
        return None if name is None else str(name)

