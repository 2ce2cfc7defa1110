"""The command service: the one way south, and the only writer of device values.

Modbus and Zenoh (and the web console) call the same operations — write a signal, write bits
of a word, read a signal, SDO read/write, NMT — by node and signal *name*, and get the same
typed results and errors (``canopen_gateway.errors``), which each adapter translates into its own
protocol's error. Values here are raw device values; engineering scaling is the adapters'
business.

Rules held here, once:
* a value is checked against its type and the profile's range before anything is sent;
* bits: a bit write (Modbus coil, Zenoh ``{"bits": ...}``) is allowed only on bits the profile
  marks ``writable``; a whole-word write must leave every other bit as it is (the last value
  sent for an RPDO word, the device's value for an SDO word), else it is refused with
  ``ValueOutOfRange`` naming the bits. A bit the gateway manages itself (the AP05 guarding
  bit) is ignored in a whole-word write. Bits of RPDO and SDO words alike are written by
  read-modify-write, one writer at a time per word;
* a configuration write (SDO) is checked against the object's range (EDS LowLimit/HighLimit,
  the profile's constraints) and refused when it would defeat the gateway's supervision of
  the node (``validation.supervision_problem``); a refusal, and an accepted write of an error
  control object, is logged at WARNING naming the write and its client (``audit.WHO``);
* SDO-backed values read north come from a cache (``master.sdo_cache_ms``, default 1000 ms):
  a read younger than that is served from it, concurrent reads share one upload, a write
  through the gateway updates it, and a boot-up or loss of the node empties it
  (``sdo_cache``).

The checks of a value are ``validation``'s; LSS inquire and the bus scan are ``bus_inquiry``'.

Every write and command is audited (``commands.audit``: who, what, outcome) when the app gives
the service an ``audit`` sink.

Imports: bus.network (the operations, routed to each node's network), bus.node.parts (the nodes), device.values (value
codecs), commands.audit, commands.bus_inquiry, commands.sdo_cache, commands.validation, errors, image, canopen.objref,
profiles, canopen.cia301. Never modbus/ or zenoh_bridge/.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import Any

from canopen_gateway.bus.network import Network, Networks
from canopen_gateway.bus.node.parts import NodeParts
from canopen_gateway.canopen.cia301 import NMT_COMMANDS, TYPE_NAMES
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.commands import bus_inquiry
from canopen_gateway.commands.audit import WHO, AuditSink, Fields, RefusalAudit, acting_as, audited
from canopen_gateway.commands.sdo_cache import SdoValueCache
from canopen_gateway.commands.validation import (
    bit_names,
    check_sdo_type,
    check_value,
    config_range_problem,
    is_supervision_object,
    supervision_problem,
    writable_mask,
)
from canopen_gateway.device.values import decode_value, encode_value
from canopen_gateway.errors import (
    GatewayError,
    NodeUnknown,
    ReadOnly,
    SupervisionWrite,
    Unmapped,
    ValueOutOfRange,
)
from canopen_gateway.image import NodeImage, SentOutputs, SignalValue
from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.profiles.derived import TextSignal, text_signals
from canopen_gateway.profiles.schema import TYPE_BITS, Signal

log = logging.getLogger("gateway.commands")


@dataclass(frozen=True)
class NodeInfo:
    """What an adapter may know of a node: names, profile (read-only), overrides, image."""

    name: str
    node_id: int
    lp: LoadedProfile
    cfg: Any  # the node's config entry (signal overrides for scaling and publishing)
    image: NodeImage
    pdo_cob_ids: tuple[int, ...]
    outputs: frozenset[str]  # signals sent in RPDOs
    #: (TPDO number, record key) of each received PDO: the signals one frame carries (TPDOs
    #: with the same signals share one record; the first number names it)
    tpdo_records: tuple[tuple[int, tuple[str, ...]], ...] = ()

    def is_output(self, name: str) -> bool:
        return name in self.outputs


def _tpdo_records(p: NodeParts) -> tuple[tuple[int, tuple[str, ...]], ...]:
    seen: dict[tuple[str, ...], int] = {}
    for codec in p.tpdos:
        if codec.names:
            seen.setdefault(codec.names, codec.number)
    return tuple((number, names) for names, number in seen.items())


def _mapped_bits(p: NodeParts, name: str) -> int | None:
    """The width of the narrowest RPDO entry carrying ``name`` (None: not in an RPDO)."""
    widths = [f.value_bits for c in p.node.by_signal.get(name, ()) if (f := c.field(name)) is not None]
    return min(widths, default=None)


class CommandService:
    def __init__(self, networks: Networks):
        #: the gateway's networks: an operation on a node goes to its network's master
        self.networks = networks
        cache_ms = networks.first.cfg.master.sdo_cache_ms
        self.sdo_cache_s = cache_ms / 1000.0
        self._sdo_cache = SdoValueCache(networks, self.sdo_cache_s)
        self._sdo_cache.ages = {
            name: net.cfg.master.sdo_cache_ms / 1000.0 for net in networks for name in net.master.nodes
        }
        self._word_locks: dict[tuple[str, str], asyncio.Lock] = {}
        self._infos: dict[str, NodeInfo] = {}
        #: every write and command (``audited``) is handed here with who, what and the
        #: outcome (``commands.audit``); None: not audited
        self.audit: AuditSink | None = None
        #: writes the adapters' gates refused, and failed logins: audited too (rate-limited)
        self.refusals = RefusalAudit(lambda: self.audit)

    # ------------------------------------------------------------------ the role (read only)
    @property
    def role(self) -> str | None:
        """This gateway's role in a hot-standby pair (``active``, ``standby``...; None
        outside a pair): what adapters show, never what they decide by. Several networks:
        the first's (``role_of`` a network's)."""
        return self.networks.first.master.role

    def role_of(self, network: str) -> str | None:
        """The role of this gateway in network ``network``'s pair (None: no pair there)."""
        return self.networks.named(network).master.role

    @property
    def pair_master_id(self) -> int | None:
        return self.networks.first.master.pair_master_id

    def require_active(self, node: str | None = None) -> None:
        """Refuse (``NotActive``) unless this gateway masters the bus: the one role gate of
        every command (the master's own), for an adapter that refuses before it reads a value;
        of the node's network, or without a node, of at least one network."""
        self.networks.require_active(node)

    def network(self, name: str | None = None) -> Network:
        """CAN network ``name`` (None: the first); ``NetworkUnknown`` otherwise."""
        return self.networks.named(name)

    def network_of(self, node: str) -> str:
        """The name of the CAN network node ``node`` is on."""
        return self.networks.of(node).name

    # ------------------------------------------------------------------ lookups
    def _part(self, name: str) -> NodeParts:
        p = self.networks.nodes.get(name)
        if p is None:
            raise NodeUnknown(name, sorted(self.networks.nodes))
        return p

    def node(self, name: str) -> NodeInfo:
        info = self._infos.get(name)
        if info is None:
            p = self._part(name)
            info = NodeInfo(
                p.name,
                p.node_id,
                p.lp,
                p.cfg,
                p.image,
                tuple(c.cob_id for c in p.tpdos) + tuple(c.cob_id for c in p.rpdos),
                frozenset(p.node.by_signal) | frozenset(t.name for t in text_signals(p.lp.profile)),
                _tpdo_records(p),
            )
            self._infos[name] = info
        return info

    def names(self) -> list[str]:
        return list(self.networks.nodes)

    def supervision(self, node: str) -> dict[str, Any]:
        """Read-only: the node's error control as resolved from config and profile (the web
        console shows it next to the node's state)."""
        st = self._part(node).settings
        return {
            "kind": st.supervision,
            "heartbeat_ms": st.heartbeat_ms,
            "heartbeat_timeout_ms": round(st.heartbeat_ms * st.heartbeat_multiple),
            "guard_time_ms": st.guard_time_ms,
            "life_time_factor": st.life_time_factor,
            "life_time_ms": st.life_time_ms,
        }

    def signal(self, node: NodeInfo | str, name: str) -> Signal:
        info = self.node(node) if isinstance(node, str) else node
        profile = info.lp.profile
        try:
            return profile.signal(name)
        except KeyError:
            pass
        ts = self._text(info.lp, name)
        if ts is not None:
            return ts.as_signal(profile.signal(ts.head))
        raise Unmapped(f"node {info.name} has no signal {name!r}")

    @staticmethod
    def _text(lp: LoadedProfile, name: str) -> TextSignal | None:
        for ts in text_signals(lp.profile):
            if ts.name == name:
                return ts
        return None

    def _managed_mask(self, p: NodeParts, name: str) -> int:
        gb = p.settings.guarding_bit
        if gb is not None and p.node.control_signal == name:
            return 1 << gb.control_bit
        return 0

    # ------------------------------------------------------------------ writes
    async def write_signal(self, node: str, name: str, value: Any) -> None:
        """Write a writable signal: an RPDO for process data, an SDO download otherwise."""
        await self.write_signals(node, {name: value})

    @audited("write", lambda _svc, node, values, **_: (node, ",".join(values), values))
    async def write_signals(self, node: str, values: dict[str, Any], *, safe: bool = False) -> None:
        """Several signals; those of RPDOs go out together (e.g. set point + control word).
        ``safe``: the safe values of the output watchdog (see ``write_safe_outputs``)."""
        p = self._part(node)
        checked: dict[str, Any] = {}
        for name, value in values.items():
            sig = self.signal(node, name)
            if sig.access == "ro":
                raise ReadOnly(f"{node}.{name} is read-only")
            checked[name] = check_value(sig, value, _mapped_bits(p, name))
        texts = {n: ts for n in checked if (ts := self._text(p.lp, n)) is not None}
        if texts:
            if len(checked) != 1:
                raise ValueOutOfRange(next(iter(texts)), values, "a text row is written alone")
            ((name, ts),) = texts.items()
            self._write_text(p, ts, checked[name])
            return
        pdo = {n: v for n, v in checked.items() if p.node.is_output(n)}
        sdo = {n: v for n, v in checked.items() if n not in pdo}
        for n, v in pdo.items():
            self._check_word(p, self.signal(node, n), v, p.image.output(n))
        for n, v in sdo.items():  # every configuration write checked before any is sent
            self._check_config_write(p, self.signal(node, n).object, v, n)
        if pdo:
            per_pdo: dict[int | None, dict[str, Any]] = {None: pdo}
            for ts in text_signals(p.lp.profile):
                # a number written to a row that showed text: that RPDO says "number" again
                if ts.head in pdo and ts.control not in pdo:
                    for c in p.node.by_signal[ts.head]:
                        ctrl = int(p.image.output(ts.control, c.number))
                        per_pdo.setdefault(c.number, {})[ts.control] = ctrl & ~(
                            1 << ts.identifier_bit
                        )
            self.networks.write_outputs(node, per_pdo, safe=safe)
        for n, v in sdo.items():
            sig = self.signal(node, n)
            if sig.bits:
                async with self._word_lock(node, n):
                    current = await self._sdo_cache.read(p, sig)
                    self._check_word(p, sig, v, current)
                    await self._sdo_cache.write(p, sig, v)
            else:
                await self._sdo_cache.write(p, sig, v)
            self._log_config_write(p, sig.object, v)

    async def write_safe_outputs(self, plan: dict[str, dict[str, Any]]) -> dict[str, str]:
        """The output watchdog tripped: write each node's safe values (``plan``: node -> RPDO
        signal -> raw value) once, through the same checks as any write. Returns, per node,
        ``"safe"`` or why it could not be done (node not operational, bus down...); one
        node's failure does not stop the others."""
        done: dict[str, str] = {}
        for node, values in plan.items():
            if not values:
                continue
            try:
                with acting_as("watchdog"):
                    await self.write_signals(node, values, safe=True)
            except GatewayError as exc:
                done[node] = str(exc)
                log.warning("safe outputs of %s not written: %s", node, exc)
            else:
                done[node] = "safe"
                log.warning("safe outputs written to %s: %s", node, values)
        return done

    def _check_word(self, p: NodeParts, sig: Signal, new: Any, current: Any) -> None:
        if not sig.bits or not isinstance(new, int):
            return
        fixed = ~(writable_mask(sig) | self._managed_mask(p, sig.name))
        changed = (int(new) ^ int(current or 0)) & fixed & ((1 << TYPE_BITS.get(sig.type_name, 64)) - 1)
        if changed:
            raise ValueOutOfRange(
                sig.name,
                new,
                f"{bit_names(sig, changed)} not writable: keep as {int(current or 0) & changed:#x}"
                f" on those bits; writable: {bit_names(sig, writable_mask(sig)) or 'none'}",
            )

    @audited("write_bits", lambda _svc, node, name, bits: (node, name, {"bits": bits}))
    async def write_bits(self, node: str, name: str, bits: dict[int, bool]) -> None:
        """Set or clear bits of a word signal (read-modify-write of the current value). A bit
        the profile does not mark writable may only be "written" with the value it has."""
        p = self._part(node)
        sig = self.signal(node, name)
        if sig.access == "ro":
            raise ReadOnly(f"{node}.{name} is read-only")
        width = min(TYPE_BITS.get(sig.type_name, 64), _mapped_bits(p, name) or 64)
        if any(not 0 <= b < width for b in bits):
            raise Unmapped(f"{node}.{name} has no bit {sorted(bits)}")
        allowed = writable_mask(sig) if sig.bits else 0
        async with self._word_lock(node, name):
            if p.node.is_output(name):
                current = int(p.image.output(name) or 0)
            else:
                current = int(await self._sdo_cache.read(p, sig))
            word = current
            for bit, on in bits.items():
                word = word | (1 << bit) if on else word & ~(1 << bit)
            changed = (word ^ current) & ~allowed
            if changed:
                raise ReadOnly(
                    f"{node}.{name}: {bit_names(sig, changed)} not writable; "
                    f"writable: {bit_names(sig, allowed) or 'none'}"
                )
            if p.node.is_output(name):
                self.networks.write_outputs(node, {None: {name: word}})
            else:
                self._check_config_write(p, sig.object, word, sig.name)
                await self._sdo_cache.write(p, sig, check_value(sig, word))
                self._log_config_write(p, sig.object, word)

    def _check_config_write(self, p: NodeParts, obj: ObjRef, value: Any, name: str = "") -> None:
        """An SDO write's value against the object's range and the node's supervision
        (``validation``); a refusal that concerns supervision is logged naming the client."""
        if not isinstance(value, int) or isinstance(value, bool):
            return
        shown = f"{name} ({obj})" if name else str(obj)
        why = config_range_problem(p.lp, obj, value)
        if why is not None:
            raise ValueOutOfRange(shown, value, why)
        master_id = self.networks.master_node_id(p.name)
        why = supervision_problem(p.name, p.settings, p.boot_steps, master_id, obj, value)
        if why is not None:
            log.warning("%s: write %s = %s refused: %s", WHO.get(), shown, value, why)
            raise SupervisionWrite(shown, value, why)

    def _log_config_write(self, p: NodeParts, obj: ObjRef, value: Any) -> None:
        """A write of an error control object that was sent: who changed what, at WARNING (the
        console's event log shows it)."""
        if is_supervision_object(obj):
            kind = p.settings.supervision
            how = "does not supervise it" if kind == "none" else f"supervises it by {kind}"
            log.warning(
                "%s wrote %s = %s on node %s (error control; the gateway %s)",
                WHO.get(), obj, value, p.name, how,
            )  # fmt: skip

    def _word_lock(self, node: str, name: str) -> asyncio.Lock:
        return self._word_locks.setdefault((node, name), asyncio.Lock())

    def _write_text(self, p: NodeParts, ts: TextSignal, raw: bytes) -> None:
        """One display row as ASCII (AP05 manual 4.1.2, table 26): characters 1-4 in the set
        point bytes 0-3, 5-6 in bytes 4-5, data identifier bit set in that RPDO's control word."""
        p.node.require_operational()
        text = raw.ljust(ts.length, b" ")
        codecs = [c for c in p.node.by_signal.get(ts.head, []) if c.index_of(ts.tail) is not None]
        if not codecs:
            raise Unmapped(f"{ts.name}: {ts.head} and {ts.tail} are not in one RPDO")
        n = codecs[0].number
        ctrl = int(p.image.output(ts.control, n)) | (1 << ts.identifier_bit)
        self.networks.write_outputs(
            p.name,
            {
                n: {
                    ts.head: int.from_bytes(text[0:4], "little", signed=True),
                    ts.tail: text[4:6],
                    ts.control: ctrl,
                }
            },
        )

    def current_text(self, p: NodeParts, ts: TextSignal, sent: SentOutputs | None = None) -> bytes:
        """The row's text as last sent (empty when the row was last sent as a number), from
        the image's output section (``sent``: one record of it, default the current one)."""
        img = p.image
        sent = img.outputs if sent is None else sent
        codec = next(c for c in p.node.by_signal[ts.head] if c.index_of(ts.tail) is not None)
        n = codec.number
        if not int(img.output(ts.control, n, sent) or 0) >> ts.identifier_bit & 1:
            return b""
        head = int(img.output(ts.head, n, sent) or 0).to_bytes(4, "little", signed=True)
        return (head + bytes(img.output(ts.tail, n, sent) or b"")).rstrip(b" \0")

    def output_value(self, node: str, name: str) -> Any:
        """The last value sent for an RPDO signal or text row (0 before anything was sent)."""
        return self.output_sample(node, name).value

    def output_sample(self, node: str, name: str) -> SignalValue:
        """An RPDO signal or text row as last written, from the image's output section:
        value (0 before anything was sent), time of the write, writes so far (``seq``)."""
        p = self._part(node)
        sent = p.image.outputs
        ts = self._text(p.lp, name)
        if ts is not None:
            value: Any = self.current_text(p, ts, sent)
        elif p.node.is_output(name):
            v = p.image.output(name, None, sent)
            value = 0 if v is None else v
        else:
            raise Unmapped(f"{node}.{name} is not sent in an RPDO")
        return SignalValue(name, value, sent.timestamp, sent.monotonic, sent.seq)

    # ------------------------------------------------------------------ reads
    async def read_signal(self, node: str, name: str) -> Any:
        """A signal's value north: the last output sent for RPDO signals, else the device's
        value by SDO (served from the cache while younger than ``sdo_cache_ms``)."""
        p = self._part(node)
        sig = self.signal(node, name)
        if sig.access == "wo":
            raise ReadOnly(f"{node}.{name} is write-only")
        if self._text(p.lp, name) is not None or p.node.is_output(name):
            return self.output_value(node, name)
        return await self._sdo_cache.read(p, sig, cached=True)

    # ------------------------------------------------------------------ SDO and NMT
    def _od_type(self, p: NodeParts, obj: ObjRef) -> str | None:
        sig = p.lp.profile.signal_for(obj)
        if sig is not None:
            return sig.type
        var = p.lp.od_var(obj)
        return None if var is None else TYPE_NAMES.get(var.data_type)

    async def sdo_read(self, node: str, obj: str | ObjRef, type_: str | None = None) -> Any:
        """Upload any object; the value decoded by ``type_`` or the dictionary's type (bytes
        when unknown)."""
        check_sdo_type(type_)
        p = self._part(node)
        o = ObjRef.parse(obj)
        data = await self.networks.sdo(node, o, None)
        t = type_ or self._od_type(p, o)
        return bytes(data) if t is None else decode_value(bytes(data), t)

    @audited("sdo_write", lambda svc, node, obj, value, type_=None: svc.sdo_audit(node, obj, value, type_))
    async def sdo_write(
        self, node: str, obj: str | ObjRef, value: Any, type_: str | None = None
    ) -> None:
        check_sdo_type(type_)
        p = self._part(node)
        o = ObjRef.parse(obj)
        if isinstance(value, (bytes, bytearray)):
            data = bytes(value)
        else:
            t = type_ or self._od_type(p, o)
            if t is None:
                raise ValueOutOfRange(str(o), value, "a type (the object is not in the EDS)")
            if isinstance(value, str) and t not in ("string", "bytes"):
                try:
                    value = float(value) if t in ("float32", "float64") else int(value, 0)
                except ValueError:
                    raise ValueOutOfRange(str(o), value, f"a number ({t})") from None
            try:
                data = encode_value(value, t)
            except ValueError as exc:
                raise ValueOutOfRange(str(o), value, str(exc)) from None
        number = self._as_integer(p, o, data, type_)
        self._check_config_write(p, o, number)
        await self.networks.sdo(node, o, data)
        self._log_config_write(p, o, number)
        sig = p.lp.profile.signal_for(o)
        if sig is not None:
            self._sdo_cache.forget(node, sig.name)

    def sdo_audit(self, node: str, obj: str | ObjRef, value: Any, type_: str | None) -> tuple[Any, ...]:
        """An SDO download as audited: the object, the value as its type reads it (a number
        for a number, whether it came as bytes or as a value) and the bytes beside it."""
        what = str(obj)
        try:
            o = ObjRef.parse(obj)
            what = str(o)
            t = type_ or self._od_type(self._part(node), o)
            data = bytes(value) if isinstance(value, (bytes, bytearray)) else None
            if t is None:
                return node, what, value, data
            if data is None:
                v = value
                if isinstance(v, str) and t not in ("string", "bytes"):
                    v = float(v) if t.startswith("float") else int(v, 0)
                data = encode_value(v, t)
            return node, what, decode_value(data, t), data
        except (GatewayError, ValueError, TypeError, OverflowError, KeyError):
            return node, what, value, value if isinstance(value, (bytes, bytearray)) else None

    def _as_integer(self, p: NodeParts, o: ObjRef, data: bytes, type_: str | None) -> int | None:
        """The integer an SDO download's bytes carry, by ``type_`` or the dictionary's type
        (None: not an integer type). Bytes of another length than the type's are read as the
        integer they hold, so a 4-byte 0 to a 16-bit 1017h is still a 0 to be checked."""
        t = type_ or self._od_type(p, o)
        if t is None or t not in TYPE_BITS or t.startswith("float") or not 0 < len(data) <= 8:
            return None
        return int.from_bytes(data, "little", signed=t.startswith("int"))

    def lss_busy(self, network: str | None = None) -> bool:
        """An LSS session is running (on network ``network``; None: the first)."""
        return self.networks.named(network).master.lss.busy()

    async def lss_inquire(
        self, address: tuple[int, int, int, int] | None = None, network: str | None = None
    ) -> dict[str, Any]:
        """LSS inquire of the slave at ``address``, else of every slave (``bus_inquiry``), on
        network ``network`` (None: the first)."""
        return await bus_inquiry.lss_inquire(self.networks.named(network).master, address)

    async def lss_fast_scan(self, known: bus_inquiry.Known, wait_s: float, first_node_id: int | None = None, count: int = 1,
                            store: bool = False, network: str | None = None) -> dict[str, Any]:  # fmt: skip
        """CiA 305 Fast Scan on network ``network`` (None: the first; ``bus_inquiry``)."""
        master = self.networks.named(network).master
        return await bus_inquiry.lss_fast_scan(master, known, wait_s, first_node_id, count, store)

    async def scan_bus(
        self, *, listen_s: float = 1.0, sdo_timeout_s: float = 0.1, network: str | None = None
    ) -> dict[str, Any]:
        """Which node ids are on the bus of network ``network`` (None: the first) and what
        they are (``bus_inquiry.scan_bus``)."""
        master = self.networks.named(network).master
        return await bus_inquiry.scan_bus(master, listen_s=listen_s, sdo_timeout_s=sdo_timeout_s)

    @audited(
        "nmt",
        lambda _svc, node, command, network=None: (node, "nmt", command)
        + ((Fields(network=network),) if network is not None else ()),
    )
    async def nmt(self, node: str, command: str, network: str | None = None) -> None:
        """NMT command to one node by name, or with ``all`` to every node of ``network``
        (None: of every network)."""
        if command not in NMT_COMMANDS:
            raise ValueOutOfRange("nmt", command, "one of " + ", ".join(NMT_COMMANDS))
        if node != "all":
            self._part(node)
        self.networks.nmt(node, command, network)
        log.info("NMT %s sent to %s", command, node if network is None else f"{node} of network {network}")
