"""What the web console shows, as JSON-able documents: the overview, the nodes table, a node's
signals (value, unit, quality, age, Modbus address, Zenoh key), EMCY history, current errors and
register-map rows.

Reads node state and values from the process image and the command service only (names,
profiles, overrides, resolved supervision); Modbus addresses come from the register map and Zenoh
keys from the key scheme, both pure functions of the config. Gateway-wide figures (bus, Modbus,
Zenoh) come from an ``overview_fn`` given by the application, which alone knows those parts.

Runs on the event loop. Imports: image, commands (types), config, northbound.regmap, northbound.keys,
northbound.scaling and northbound.summary (pure modules, no protocol library), canopen.cia301 (the
error register bits), profiles.schema, profiles.layout, canopen.states. Never modbus/, zenoh_bridge/ or bus/.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from canopen_gateway.canopen.cia301 import register_bits
from canopen_gateway.canopen.states import LinkState, NmtState
from canopen_gateway.commands import CommandService
from canopen_gateway.config import Config
from canopen_gateway.image import NodeImage, ProcessImage, Quality
from canopen_gateway.northbound.keys import is_published, is_writable, prefix_of, set_key, value_key
from canopen_gateway.northbound.regmap import RegisterMap
from canopen_gateway.northbound.scaling import Scaling, bits_of, engineering
from canopen_gateway.northbound.summary import QUALITY_TEXT, serves_values, summarize, worst_quality
from canopen_gateway.profiles.layout import tpdo_objects
from canopen_gateway.profiles.schema import Signal

#: Bits of an average CAN 2.0A frame with 8 data bytes, stuff bits not counted (ISO 11898-1:
#: SOF 1, identifier 11, RTR/IDE/r0 3, DLC 4, data 64, CRC 15 + delimiter 1, ACK 2, EOF 7,
#: intermission 3). The bus load shown is an estimate from frames/s.
BITS_PER_FRAME = 111

NMT_WORDS = {
    NmtState.UNKNOWN: "unknown",
    NmtState.BOOTUP: "boot-up",
    NmtState.STOPPED: "stopped",
    NmtState.OPERATIONAL: "operational",
    NmtState.PRE_OPERATIONAL: "pre-operational",
}
LINK_WORDS = {
    LinkState.NOT_USED: "not used",
    LinkState.OK: "ok",
    LinkState.FAULT: "fault",
    LinkState.UNKNOWN: "unknown",
}

#: beside the status of a node whose PDOs map nothing (``canopen-gateway check`` warns of it)
NO_PROCESS_DATA = "no process data: its PDOs map nothing"
#: Modbus tables as the node page abbreviates them (its caption spells them out)
TABLE_SHORT = {"ir": "IR", "hr": "HR", "di": "DI", "co": "coil"}

OverviewFn = Callable[[], dict[str, Any]]


@dataclass(frozen=True)
class SignalMeta:
    """What does not change about a signal while the gateway runs."""

    sig: Signal
    scaling: Scaling
    source: str  # "TPDO" | "RPDO" | "SDO"
    modbus: str  # "IR 100-101 @ unit 1" or ""
    zenoh: tuple[str, ...]  # keys: value (publication or SDO read), set

    def doc(self) -> dict[str, Any]:
        s = self.sig
        return {
            "name": s.name,
            "object": str(s.object),
            "type": s.type,
            "access": s.access,
            "source": self.source,
            "unit": self.scaling.unit,
            "scale": self.scaling.scale,
            "offset": self.scaling.offset,
            "min": s.min,
            "max": s.max,
            "description": s.description,
            "modbus": self.modbus,
            "zenoh": list(self.zenoh),
            "writable": is_writable(s),
            "bits": [{"name": b.name, "bit": b.bit, "writable": b.writable} for b in s.bits],
        }


def _age(now: float, mono: float) -> float | None:
    return None if not mono else round(max(0.0, now - mono), 3)


class ConsoleModel:
    """Builds the console's documents from the image, the command service and the config."""

    def __init__(
        self,
        cfg: Config,
        image: ProcessImage,
        commands: CommandService,
        overview_fn: OverviewFn | None = None,
        *,
        regmap: RegisterMap,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.cfg = cfg
        self.image = image
        self.commands = commands
        self.overview_fn = overview_fn
        self.clock = clock
        self.regmap = regmap
        self.prefix = prefix_of(cfg)
        #: per node, the signals its TPDOs carry (their worst quality is the node's status,
        #: as Modbus input register 0 of the node)
        self.process: dict[str, frozenset[str]] = {}
        for p in self.regmap.points:
            if p.node and p.kind == "signal" and p.table == "ir":
                self.process[p.node] = self.process.get(p.node, frozenset()) | {p.name}
        self.meta: dict[str, dict[str, SignalMeta]] = {n: self._meta(n) for n in commands.names()}
        self._rates: dict[str, float] = {}
        self._rate_sample: tuple[float, dict[str, int]] | None = None

    # ------------------------------------------------------------------ static
    def _meta(self, name: str) -> dict[str, SignalMeta]:
        info = self.commands.node(name)
        where: dict[str, list[str]] = {}
        for p in self.regmap.node_points(name):
            if p.kind == "signal":
                span = str(p.address) if p.count == 1 else f"{p.address}-{p.end - 1}"
                where.setdefault(p.name, []).append(f"{TABLE_SHORT[p.table]} {span} @ unit {p.unit}")
        out = {}
        inputs = tpdo_objects(info.lp.profile, getattr(info.cfg, "pdo_variant", None))
        for s in info.lp.profile.signals:
            ov = info.cfg.signals.get(s.name) if info.cfg is not None else None
            if s.transport == "sdo":
                source = "SDO"
            elif info.is_output(s.name):
                source = "RPDO"
            elif s.name in self.process.get(name, ()):
                source = "TPDO"
            else:
                source = "TPDO (not in this PDO layout)"
            keys = []
            publish_off = ov is not None and ov.publish == "off"
            if not self.cfg.zenoh.enabled:
                keys.append("Zenoh off")
            else:
                if (is_published(s, inputs) and not publish_off) or (
                    s.transport == "sdo" and s.access != "wo"
                ):
                    keys.append(value_key(self.prefix, name, s.name))
                if is_writable(s):
                    keys.append(set_key(self.prefix, name, s.name))
            modbus = "; ".join(where.get(s.name, [])) if self.cfg.modbus.enabled else "Modbus off"
            out[s.name] = SignalMeta(s, Scaling.of(s, ov), source, modbus, tuple(keys))
        return out

    def register_rows(self, name: str) -> list[dict[str, str]]:
        """The node's rows of the register map (bits of one word grouped), as in
        ``canopen-gateway registers``."""
        if not self.cfg.modbus.enabled:
            return []
        header = self.regmap.HEADER
        return [
            dict(zip(header, row, strict=True))
            for row in self.regmap.grouped_rows()
            if row[5] == name
        ]

    # ------------------------------------------------------------------ overview
    def overview(self) -> dict[str, Any]:
        doc: dict[str, Any] = dict(self.overview_fn()) if self.overview_fn is not None else {}
        counters = self.image.counters.snapshot()
        now = self.clock()
        sample = {"frames_in": counters["frames_in"], "frames_out": counters["frames_out"]}
        sample |= {k: int(v) for k, v in (doc.get("counters") or {}).items()}
        nets: dict[str, Any] = doc.get("networks") or {}
        for name, net in nets.items():  # each network's frames: its rates and bus load
            sample |= {f"{name}/frames_in": net["frames_in"], f"{name}/frames_out": net["frames_out"]}
        if self._rate_sample is None:
            self._rate_sample = (now, sample)
        else:
            t0, old = self._rate_sample
            if now - t0 >= 1.0:
                self._rates = {k: (v - old.get(k, v)) / (now - t0) for k, v in sample.items()}
                self._rate_sample = (now, sample)
        rates = {k: round(v, 1) for k, v in self._rates.items() if "/" not in k}
        for name, net in nets.items():
            net_rates = {k: round(self._rates.get(f"{name}/{k}", 0.0), 1) for k in ("frames_in", "frames_out")}
            net["rates"] = net_rates
            net["bus_load_percent"] = _load(net_rates, net.get("bitrate"))
        bitrate = self.cfg.can.bitrate
        frames_s = rates.get("frames_in", 0.0) + rates.get("frames_out", 0.0)
        doc.update(
            {
                "uptime_s": round(now - self.image.started_monotonic, 1),
                "frames_in": counters["frames_in"],
                "frames_out": counters["frames_out"],
                "decode_errors": counters["decode_errors"],
                "unknown_cob_id": counters["unknown_cob_id"],
                "bus_errors": counters["bus_errors"],
                "rates": rates,
                "bitrate": bitrate,
                "bus_load_percent": (
                    round(100.0 * frames_s * BITS_PER_FRAME / bitrate, 1) if bitrate else None
                ),
                "nodes": len(self.image.nodes),
                # usable values: a node whose PDOs map nothing has none to use
                "nodes_usable": sum(
                    1
                    for n in self.image.nodes.values()
                    if n.usable() and serves_values(n, self.process.get(n.name, ()))
                ),
            }
        )
        return doc

    # ------------------------------------------------------------------ nodes
    def quality(self, node: NodeImage, now: float) -> Quality:
        """The node's worst process-data quality (as Modbus input register 0 of the node)."""
        return worst_quality(node, self.process.get(node.name, ()), now)

    def node_row(self, name: str, now: float | None = None) -> dict[str, Any]:
        now = self.clock() if now is None else now
        info = self.commands.node(name)
        node = info.image
        s = summarize(node, now, self.process.get(name, ()))
        sup = self.commands.supervision(name)
        if sup["kind"] == "heartbeat":
            timing = (
                f"heartbeat {sup['heartbeat_ms']} ms, lost after {sup['heartbeat_timeout_ms']} ms"
                if sup["heartbeat_ms"]
                else "heartbeat off"
            )
        elif sup["kind"] == "guarding":
            timing = (
                f"node guarding {sup['guard_time_ms']} ms x {sup['life_time_factor']}"
                f" = {sup['life_time_ms']} ms"
            )
        else:
            timing = "none"
        age = s.data_age_s
        emcy = s.last_emcy
        q = s.quality
        assert q is not None
        return {
            "name": name,
            "node_id": info.node_id,
            "network": node.network,
            "profile": info.lp.family,
            "title": info.lp.profile.title,
            "quality": QUALITY_TEXT[q],
            # why a node that answers is bad all the same: nothing to serve
            "quality_note": "" if serves_values(node, self.process.get(name, ())) else NO_PROCESS_DATA,
            "alive": s.alive,
            "presence": s.presence,
            "usable": s.usable,
            "nmt_state": NMT_WORDS.get(s.nmt_state, s.nmt_state.name.lower()),
            "lifecycle": s.lifecycle,
            "supervision": sup["kind"],
            "supervision_timing": timing,
            "link": LINK_WORDS.get(s.link, str(s.link)),
            "link_faults": s.link_fault_count,
            "last_emcy": None
            if emcy is None
            else {"code": f"0x{emcy.code:04X}", "text": emcy.text, "ts": emcy.timestamp},
            "emcy_count": s.emcy_count,
            "current_errors": [f"0x{c:04X}" for c in s.current_errors],
            "boots": s.boot_count,
            "losses": s.loss_count,
            "data_age_s": None if age is None else round(age, 3),
            "last_sdo_abort": f"0x{s.last_sdo_abort:08X}" if s.last_sdo_abort else "",
            "last_error": s.last_error,
            "outputs": s.outputs,
        }

    def node_rows(self) -> list[dict[str, Any]]:
        now = self.clock()
        return [self.node_row(n, now) for n in self.commands.names()]

    def emcy(self, name: str) -> dict[str, Any]:
        node = self.commands.node(name).image
        h = node.health
        texts: dict[int, str] = {}
        for rec in h.emcy_history:
            texts.setdefault(rec.code, rec.text)
        return {
            "history": [
                {
                    "code": f"0x{rec.code:04X}",
                    "text": rec.text,
                    "register": f"0x{rec.register:02X}",
                    "register_bits": register_bits(rec.register),
                    "manufacturer": bytes(rec.manufacturer).hex(" "),
                    "ts": rec.timestamp,
                }
                for rec in reversed(h.emcy_history)
            ],
            "current": [
                {"code": f"0x{c:04X}", "text": texts.get(c, "")} for c in h.current_errors
            ],
        }

    def values(self, name: str, only: set[str] | None = None) -> dict[str, dict[str, Any]]:
        """The live part of each signal: value (engineering), text, quality, age, seq."""
        info = self.commands.node(name)
        node = info.image
        snap = node.snapshot()
        now = self.clock()
        out: dict[str, dict[str, Any]] = {}
        for sname, meta in self.meta[name].items():
            if only is not None and sname not in only:
                continue
            s = meta.sig
            if meta.source == "RPDO":
                raw = self.commands.output_value(name, sname)
                out[sname] = {"value": engineering(s, raw, meta.scaling), "quality": "output"}
                continue
            sv = snap[sname] if sname in snap else None
            if sv is None or (sv.seq == 0 and meta.source != "TPDO"):
                out[sname] = {"value": None, "quality": "on request"}
                continue
            q = node.quality(sv, now)
            d: dict[str, Any] = {
                "value": engineering(s, sv.value, meta.scaling) if sv.seq else None,
                "quality": QUALITY_TEXT[q],
                "age_s": _age(now, sv.monotonic) if sv.seq else None,
                "seq": sv.seq,
            }
            if sv.seq:
                text = s.values.get(sv.value) if isinstance(sv.value, int) else None
                if text is not None:
                    d["text"] = text
                bits = bits_of(s, sv.value)
                if bits is not None:
                    d["bits"] = bits
            out[sname] = d
        return out

    def node_detail(self, name: str) -> dict[str, Any]:
        info = self.commands.node(name)
        return {
            "row": self.node_row(name),
            "signals": [m.doc() for m in self.meta[name].values()],
            "values": self.values(name),
            "emcy": self.emcy(name),
            "registers": self.register_rows(name),
            "zenoh_prefix": f"{self.prefix}/{name}",
            "modbus_unit": next(
                (p.unit for p in self.regmap.node_points(name)), info.node_id
            ),
        }


def _load(rates: dict[str, float], bitrate: int | None) -> float | None:
    """A bus's load in percent, estimated from its frames a second (None: no bit rate)."""
    frames_s = rates.get("frames_in", 0.0) + rates.get("frames_out", 0.0)
    return round(100.0 * frames_s * BITS_PER_FRAME / bitrate, 1) if bitrate else None
