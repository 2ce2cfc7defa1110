"""CAN frames in CANopen words, with what the configuration knows: one line per frame.

``FrameDecoder(cfg, nodes).decode(msg)`` names the service by COB-ID (CiA 301 7.3.3, pre-defined
connection set) and decodes the data: NMT commands with the target node, heartbeat states and
boot-up, EMCY with the device's own text (profile ``emcy:``) and the error register bits, SDO
requests and answers with the object and the abort text, PDOs of configured nodes with signal
names and engineering values (the codecs of the resolved nodes, ``canopen_gateway.device.resolved``: the
mapping the boot configuration leaves in the device, as the gateway decodes it), SYNC, TIME and LSS. A frame of an unconfigured node id is named by its
function. Pure: no bus, no clock.

Imports: config, profiles, pdo.codec, device.resolved (types), canopen.emcy, canopen.cia301, canopen.connection_set,
canopen.states, canopen.objref.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

from canopen_gateway.canopen.cia301 import abort_text
from canopen_gateway.canopen.connection_set import describe_cob_id
from canopen_gateway.canopen.emcy import decode_emcy
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.canopen.states import NMT_BY_CODE, NmtState
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.pdo.codec import RpdoCodec, TpdoCodec
from canopen_gateway.profiles import LoadedProfile

#: the kinds ``monitor --kind`` filters by
KINDS = ("nmt", "sync", "time", "emcy", "pdo", "sdo", "heartbeat", "lss", "other")

# CiA 301 7.2.4.3: command specifiers of SDO frames (bits 7..5 of byte 0)
_CLIENT_CS = {0: "download segment", 1: "download", 2: "upload", 3: "upload segment",
              4: "abort", 5: "block upload", 6: "block download"}  # fmt: skip
_SERVER_CS = {0: "upload segment", 1: "download segment answer", 2: "upload answer",
              3: "download answer", 4: "abort", 5: "block download", 6: "block upload"}  # fmt: skip
# CiA 305 LSS command specifiers (byte 0): the gateway's, identify (46h..4Ch, answers 4Fh and 50h)
# and Fast Scan (51h, answered by 4Fh)
_LSS_CS = {0x04: "switch state global", 0x11: "configure node id", 0x13: "configure bit timing",
           0x15: "activate bit timing", 0x17: "store configuration", 0x40: "switch selective vendor",
           0x41: "switch selective product", 0x42: "switch selective revision",
           0x43: "switch selective serial", 0x44: "switch selective answer",
           0x46: "identify remote slave vendor", 0x47: "identify remote slave product",
           0x48: "identify remote slave revision low", 0x49: "identify remote slave revision high",
           0x4A: "identify remote slave serial low", 0x4B: "identify remote slave serial high",
           0x4C: "identify non-configured", 0x4F: "identify slave answer",
           0x50: "identify non-configured answer", 0x51: "fast scan",
           0x5A: "inquire vendor", 0x5B: "inquire product", 0x5C: "inquire revision",
           0x5D: "inquire serial", 0x5E: "inquire node id"}  # fmt: skip


@dataclass(frozen=True)
class Decoded:
    """One frame in words: its ``kind`` (one of KINDS), the node id it concerns (None for
    broadcasts), the configured node's name if any, and the text."""

    kind: str
    node_id: int | None
    node: str | None
    service: str
    text: str


@dataclass
class _NodeInfo:
    name: str
    node_id: int
    lp: LoadedProfile
    tpdos: dict[int, TpdoCodec]
    rpdos: dict[int, RpdoCodec]


def _state_word(byte: int) -> str:
    if byte == 0:
        return "boot-up"
    try:
        return NmtState(byte & 0x7F).name.lower().replace("_", "-")
    except ValueError:
        return f"undefined state 0x{byte:02X}"


class FrameDecoder:
    """Decodes frames with the knowledge of one configuration (see the module docstring)."""

    def __init__(self, cfg: Config, nodes: dict[str, ResolvedNode]):
        self.by_id: dict[int, _NodeInfo] = {}
        self.pdo_owner: dict[int, tuple[_NodeInfo, str]] = {}
        for n in cfg.nodes:
            rn = nodes[n.name].require()
            tpdos, rpdos = rn.tpdos, rn.rpdos
            info = _NodeInfo(
                n.name, n.node_id, rn.lp, {c.cob_id: c for c in tpdos}, {c.cob_id: c for c in rpdos}
            )
            self.by_id[n.node_id] = info
            for t in tpdos:
                self.pdo_owner[t.cob_id] = (info, f"TPDO{t.number}")
            for r in rpdos:
                self.pdo_owner[r.cob_id] = (info, f"RPDO{r.number}")
        self.master_id = cfg.master.node_id

    def node_name(self, node_id: int | None) -> str | None:
        info = self.by_id.get(node_id) if node_id is not None else None
        return info.name if info else None

    def decode(self, cob_id: int, data: bytes, remote: bool = False) -> Decoded:
        data = bytes(data)
        if cob_id in self.pdo_owner:
            info, service = self.pdo_owner[cob_id]
            if remote:
                return Decoded("pdo", info.node_id, info.name, service, "remote request (RTR)")
            return Decoded("pdo", info.node_id, info.name, service, self._pdo(info, cob_id, data))
        if cob_id == 0x000:
            return self._nmt(data)
        if cob_id == 0x080:
            text = f"counter {data[0]}" if data else ""
            return Decoded("sync", None, None, "SYNC", text)
        if cob_id == 0x100:
            return Decoded("time", None, None, "TIME", data.hex(" "))
        if cob_id in (0x7E4, 0x7E5):
            return self._lss(cob_id, data)
        base, node_id = cob_id & 0x780, cob_id & 0x7F
        name = self.node_name(node_id)
        if base == 0x080 and node_id:
            return self._emcy(node_id, name, data)
        if base in (0x580, 0x600) and node_id:
            return self._sdo(node_id, name, data, request=base == 0x600)
        if base == 0x700 and node_id:
            if remote:
                return Decoded("heartbeat", node_id, name, "guarding", "remote request (RTR)")
            if not data:
                return Decoded("heartbeat", node_id, name, "heartbeat", "empty")
            toggle = " (toggle 1)" if data[0] & 0x80 else ""
            who = " (this gateway's id)" if node_id == self.master_id else ""
            return Decoded("heartbeat", node_id, name, "heartbeat", _state_word(data[0]) + toggle + who)
        desc = describe_cob_id(cob_id)
        kind = "pdo" if desc[:4] in ("TPDO", "RPDO") else "other"
        service = desc.split(" of ")[0]
        return Decoded(kind, node_id or None, name, service, data.hex(" ") or "(no data)")

    def _nmt(self, data: bytes) -> Decoded:
        if len(data) < 2:
            return Decoded("nmt", None, None, "NMT", f"short frame {data.hex(' ')}")
        command = NMT_BY_CODE.get(data[0], f"command 0x{data[0]:02X}")
        if data[1] == 0:
            return Decoded("nmt", None, None, "NMT", f"{command} to every node")
        name = self.node_name(data[1])
        return Decoded("nmt", data[1], name, "NMT", f"{command} to node id {data[1]}")

    def _emcy(self, node_id: int, name: str | None, data: bytes) -> Decoded:
        info = self.by_id.get(node_id)
        texts = info.lp.profile.emcy if info else None
        try:
            emcy = decode_emcy(data, texts)
        except ValueError as exc:
            return Decoded("emcy", node_id, name, "EMCY", str(exc))
        return Decoded("emcy", node_id, name, "EMCY", str(emcy).removeprefix("EMCY "))

    def _sdo(self, node_id: int, name: str | None, data: bytes, request: bool) -> Decoded:
        service = "SDO request" if request else "SDO answer"
        if not data:
            return Decoded("sdo", node_id, name, service, "empty")
        cs = data[0] >> 5
        word = (_CLIENT_CS if request else _SERVER_CS).get(cs, f"command 0x{data[0]:02X}")
        if len(data) < 4 or cs in (0,) or (not request and cs in (0, 1)) or (request and cs == 3):
            return Decoded("sdo", node_id, name, service, f"{word} {data[1:].hex(' ')}".rstrip())
        index, sub = data[1] | (data[2] << 8), data[3]
        obj = f"0x{index:04X}:{sub:02X}"
        info = self.by_id.get(node_id)
        if info is not None:
            var = info.lp.od_var(ObjRef(index, sub))
            if var is not None and getattr(var, "name", None):
                obj += f" ({var.name})"
        if cs == 4:
            code = int.from_bytes(data[4:8].ljust(4, b"\0"), "little")
            return Decoded("sdo", node_id, name, service, f"abort {obj}: 0x{code:08X} {abort_text(code)}")
        text = f"{word} {obj}"
        expedited = data[0] & 0x02
        if expedited and ((request and cs == 1) or (not request and cs == 2)):
            size = 4 - ((data[0] >> 2) & 0x3) if data[0] & 0x01 else 4
            value = int.from_bytes(data[4 : 4 + size], "little")
            text += f" = {value} (0x{value:0{size * 2}X})"
        elif (request and cs == 1) or (not request and cs == 2):
            total = int.from_bytes(data[4:8], "little") if data[0] & 0x01 else None
            text += " segmented" + (f", {total} bytes" if total is not None else "")
        return Decoded("sdo", node_id, name, service, text)

    def _pdo(self, info: _NodeInfo, cob_id: int, data: bytes) -> str:
        codec: Any = info.tpdos.get(cob_id)
        if codec is None:
            rp = info.rpdos[cob_id]
            names = rp.names
            tp = TpdoCodec(rp.cob_id, rp.number, rp.fields)  # the same layout, read as a TPDO
            codec = tp
        else:
            names = codec.names
        try:
            values = codec.decode(data)
        except ValueError as exc:
            return str(exc)
        parts = []
        profile = info.lp.profile
        for n, v in zip(names, values, strict=False):
            sig = profile.signal(n)
            parts.append(f"{n}={_engineering(v, sig.scale, sig.offset)}{_unit(sig.unit)}")
        return " ".join(parts) or data.hex(" ")

    def _lss(self, cob_id: int, data: bytes) -> Decoded:
        service = "LSS request" if cob_id == 0x7E5 else "LSS answer"
        if not data:
            return Decoded("lss", None, None, service, "empty")
        word = _LSS_CS.get(data[0], f"command 0x{data[0]:02X}")
        return Decoded("lss", None, None, service, f"{word} {data[1:].hex(' ')}".rstrip())


def _engineering(raw: Any, scale: float, offset: float) -> str:
    if isinstance(raw, (bytes, bytearray)):
        return repr(bytes(raw).rstrip(b"\0").decode("ascii", errors="replace"))
    if scale == 1.0 and offset == 0.0:
        return str(raw)
    return f"{raw * scale + offset:g}"


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def node_filter(cfg: Config, items: Collection[str]) -> set[int]:
    """Node ids from names or numbers; ValueError naming what is unknown."""
    ids = set()
    names = {n.name: n.node_id for n in cfg.nodes}
    for item in items:
        if item in names:
            ids.add(names[item])
        elif item.isdigit() and 1 <= int(item) <= 127:
            ids.add(int(item))
        else:
            raise ValueError(
                f"--node {item!r}: not a node of the config ({', '.join(names) or 'none'}) "
                "nor a node id 1..127"
            )
    return ids


def kind_filter(items: Collection[str]) -> set[str]:
    unknown = [k for k in items if k not in KINDS]
    if unknown:
        raise ValueError(f"--kind {', '.join(unknown)}: kinds are {', '.join(KINDS)}")
    return set(items)
