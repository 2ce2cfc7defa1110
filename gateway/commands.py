"""The command service: the one way south.

Modbus and Zenoh call the same operations (write a signal, write bits of a word, SDO read/write,
NMT) and get the same typed results and errors (``gateway.errors``), which each adapter
translates into its own protocol's error. Values here are raw device values; engineering
scaling is the adapters' business.

Imports: bus.master (for the operations), errors, image, objref. Never modbus/ or zenoh_bridge/.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from gateway.bus.codec import RpdoCodec
from gateway.bus.master import NMT_COMMANDS, Master, NodeRuntime
from gateway.errors import NodeNotOperational, NodeUnknown, ReadOnly, Unmapped, ValueOutOfRange
from gateway.image import NmtState
from gateway.objref import ObjRef
from gateway.profiles.derived import TextSignal, text_signals
from gateway.profiles.schema import TYPE_BITS, Signal

log = logging.getLogger("gateway.commands")


def type_range(type_: str) -> tuple[int, int] | None:
    bits = TYPE_BITS.get(type_)
    if bits is None or type_ == "float32":
        return None
    if type_ == "bool":
        return 0, 1
    if type_.startswith("int"):
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def check_value(sig: Signal, value: Any) -> Any:
    """Validate a raw value for a signal; returns it normalised or raises ValueOutOfRange."""
    if sig.type in ("string", "bytes"):
        if isinstance(value, str):
            try:
                raw = value.encode("ascii")
            except UnicodeEncodeError:
                raise ValueOutOfRange(sig.name, value, "ASCII text only") from None
        elif isinstance(value, (bytes, bytearray)):
            raw = bytes(value)
        else:
            raise ValueOutOfRange(sig.name, value, "text expected")
        if sig.length is not None and len(raw) > sig.length:
            raise ValueOutOfRange(sig.name, value, f"at most {sig.length} characters")
        if sig.type == "string" and any(b < 0x20 or b > 0x7E for b in raw.rstrip(b"\0")):
            raise ValueOutOfRange(sig.name, value, "printable ASCII characters only")
        return raw
    if sig.type == "float32":
        try:
            v: float | int = float(value)
        except (TypeError, ValueError):
            raise ValueOutOfRange(sig.name, value, "a number") from None
    else:
        if isinstance(value, float) and not value.is_integer():
            raise ValueOutOfRange(sig.name, value, "an integer")
        try:
            v = int(value)
        except (TypeError, ValueError):
            raise ValueOutOfRange(sig.name, value, "an integer") from None
        rng = type_range(sig.type)
        if rng and not rng[0] <= v <= rng[1]:
            raise ValueOutOfRange(sig.name, value, f"{rng[0]}..{rng[1]} ({sig.type})")
    # profile min/max are engineering values (raw x scale + offset)
    eng = v * sig.scale + sig.offset
    if sig.min is not None and eng < sig.min - 1e-9:
        raise ValueOutOfRange(sig.name, value, f">= {sig.min:g} {sig.unit}".rstrip())
    if sig.max is not None and eng > sig.max + 1e-9:
        raise ValueOutOfRange(sig.name, value, f"<= {sig.max:g} {sig.unit}".rstrip())
    return v


class CommandService:
    def __init__(self, master: Master):
        self.master = master

    def node(self, name: str) -> NodeRuntime:
        rt = self.master.nodes.get(name)
        if rt is None:
            raise NodeUnknown(name, sorted(self.master.nodes))
        return rt

    def signal(self, rt: NodeRuntime, name: str) -> Signal:
        try:
            return rt.lp.profile.signal(name)
        except KeyError:
            pass
        ts = self._text(rt, name)
        if ts is not None:
            return ts.as_signal(rt.lp.profile.signal(ts.head))
        raise Unmapped(f"node {rt.name} has no signal {name!r}")

    @staticmethod
    def _text(rt: NodeRuntime, name: str) -> TextSignal | None:
        for ts in text_signals(rt.lp.profile):
            if ts.name == name:
                return ts
        return None

    def _require_operational(self, rt: NodeRuntime) -> None:
        h = rt.image.health
        if not h.alive:
            raise NodeNotOperational(rt.name, "not alive (lost or never booted)")
        if h.nmt_state != NmtState.OPERATIONAL:
            raise NodeNotOperational(rt.name, f"NMT state {h.nmt_state.name}")

    async def write_signal(self, node: str, name: str, value: Any) -> None:
        """Write a writable signal: an RPDO for process data, an SDO download otherwise."""
        rt = self.node(node)
        sig = self.signal(rt, name)
        if sig.access == "ro":
            raise ReadOnly(f"{node}.{name} is read-only")
        v = check_value(sig, value)
        ts = self._text(rt, name)
        if ts is not None:
            self._write_text(rt, ts, v)
            return
        if sig.transport == "pdo" and name in rt.rpdo_by_signal:
            await self.write_signals(node, {name: value})
            return
        await self.master.sdo_download(rt, sig.object, v, sig.type)

    def _write_text(self, rt: NodeRuntime, ts: TextSignal, raw: bytes) -> None:
        """One display row as ASCII (AP05 manual 4.1.2, table 26): characters 1-4 in the set
        point bytes 0-3, 5-6 in bytes 4-5, data identifier bit set in that RPDO's control word."""
        self._require_operational(rt)
        text = raw.ljust(ts.length, b" ")
        codecs = [c for c in rt.rpdo_by_signal[ts.head] if ts.tail in c.names]
        if not codecs:
            raise Unmapped(f"{ts.name}: {ts.head} and {ts.tail} are not in one RPDO")
        codec = codecs[0]
        saved = dict(codec.values)
        codec.set(ts.head, int.from_bytes(text[0:4], "little", signed=True))
        codec.set(ts.tail, text[4:6])
        codec.set(ts.control, int(codec.get(ts.control)) | (1 << ts.identifier_bit))
        try:
            self.master.send_rpdo(rt, codec)
        except Exception:
            codec.values.update(saved)
            raise

    def current_text(self, rt: NodeRuntime, ts: TextSignal) -> bytes:
        """The row's text as last sent (empty when the row was last sent as a number)."""
        codec = next(c for c in rt.rpdo_by_signal[ts.head] if ts.tail in c.names)
        if not int(codec.get(ts.control)) >> ts.identifier_bit & 1:
            return b""
        head = int(codec.get(ts.head)).to_bytes(4, "little", signed=True)
        return (head + bytes(codec.get(ts.tail))).rstrip(b" \0")

    async def write_signals(self, node: str, values: dict[str, Any]) -> None:
        """Several signals of one RPDO in one frame (e.g. set point + control word)."""
        rt = self.node(node)
        checked = {}
        for name, value in values.items():
            sig = self.signal(rt, name)
            if sig.access == "ro":
                raise ReadOnly(f"{node}.{name} is read-only")
            checked[name] = check_value(sig, value)
        pdo_names = [n for n in checked if n in rt.rpdo_by_signal]
        sdo_names = [n for n in checked if n not in rt.rpdo_by_signal]
        if pdo_names:
            self._require_operational(rt)
            # Which RPDOs go out: those carrying a signal mapped only there; a signal mapped in
            # several RPDOs (a shared control word) alone goes out in the last of them.
            send: dict[int, RpdoCodec] = {}
            for n in pdo_names:
                cs = rt.rpdo_by_signal[n]
                if len(cs) == 1:
                    send[cs[0].number] = cs[0]
            if not send:
                last = rt.rpdo_by_signal[pdo_names[0]][-1]
                send[last.number] = last
            saved = {c.number: dict(c.values) for cs in rt.rpdo_by_signal.values() for c in cs}
            for n in pdo_names:
                for c in rt.rpdo_by_signal[n]:
                    c.set(n, checked[n])
            for ts in text_signals(rt.lp.profile):
                # a number written to a row that showed text: that RPDO says "number" again
                if ts.head in checked and ts.control not in checked:
                    for c in rt.rpdo_by_signal[ts.head]:
                        c.set(ts.control, int(c.get(ts.control)) & ~(1 << ts.identifier_bit))
            try:
                for codec in sorted(send.values(), key=lambda c: c.number):
                    self.master.send_rpdo(rt, codec)
            except Exception:
                for c in rt.rpdos:
                    c.values.update(saved.get(c.number, {}))
                raise
            for n in pdo_names:
                self._mirror(rt, n, checked[n])
        for n in sdo_names:
            sig = self.signal(rt, n)
            await self.master.sdo_download(rt, sig.object, checked[n], sig.type)

    async def write_bits(self, node: str, name: str, bits: dict[int, bool]) -> None:
        """Set or clear bits of a writable word signal (read-modify-write of the last value)."""
        rt = self.node(node)
        sig = self.signal(rt, name)
        if sig.access == "ro":
            raise ReadOnly(f"{node}.{name} is read-only")
        current = int(self.current_output(rt, name) or 0)
        for bit, on in bits.items():
            current = current | (1 << bit) if on else current & ~(1 << bit)
        await self.write_signal(node, name, current)

    def current_output(self, rt: NodeRuntime, name: str) -> Any:
        """The last value sent for a writable process-data signal (None if SDO-backed)."""
        ts = self._text(rt, name)
        if ts is not None:
            return self.current_text(rt, ts)
        codecs = rt.rpdo_by_signal.get(name)
        return codecs[-1].get(name) if codecs else None

    def _mirror(self, rt: NodeRuntime, name: str, value: Any) -> None:
        sig = rt.image.signals.get(name)
        if sig is not None:
            sig.value = value
            sig.timestamp = time.time()
            sig.seq += 1

    async def read_signal(self, node: str, name: str) -> Any:
        """Read an SDO-backed signal from the device (process data comes from the image)."""
        rt = self.node(node)
        sig = self.signal(rt, name)
        if sig.access == "wo":
            raise ReadOnly(f"{node}.{name} is write-only")
        ts = self._text(rt, name)
        if ts is not None:
            return self.current_text(rt, ts)
        return await self.master.sdo_upload(rt, sig.object, sig.type)

    async def sdo_read(self, node: str, obj: str | ObjRef, type_: str | None = None) -> Any:
        rt = self.node(node)
        return await self.master.sdo_upload(rt, ObjRef.parse(obj), type_)

    async def sdo_write(
        self, node: str, obj: str | ObjRef, value: Any, type_: str | None = None
    ) -> None:
        rt = self.node(node)
        await self.master.sdo_download(rt, ObjRef.parse(obj), value, type_)

    def nmt(self, node: str, command: str) -> None:
        """NMT command to one node by name, or to all nodes with ``all``."""
        if command not in NMT_COMMANDS:
            raise ValueOutOfRange("nmt", command, "one of " + ", ".join(NMT_COMMANDS))
        node_id = 0 if node == "all" else self.node(node).node_id
        self.master.nmt_send(node_id, command)
        log.info("NMT %s sent to %s", command, node)
