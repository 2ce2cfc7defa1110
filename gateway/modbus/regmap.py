"""The Modbus register map, compiled from profiles + config (pure: no I/O, no pymodbus).

Layout (``modbus.layout: per_node``, the default): one unit id per node (default its node id)
and one for the gateway itself (``modbus.gateway_unit_id``, default 247). Within a node's unit:

* input registers 0..15: diagnostics (quality, NMT state, alive, data age, EMCY, losses, link)
* input registers 100..: process data read from the node (TPDO signals), in profile order
* holding register 0: NMT command (write 1 start, 2 stop, 128 pre-op, 129 reset, 130 reset comm;
  reads the NMT state)
* holding registers 100..: writable process data (RPDO signals), then configuration objects
  served by SDO
* discrete inputs 0..3: alive, operational, link ok, error active; 100..: bits of read-only
  word signals, 16 (or 32) addresses per word: address = base + bit
* coils 100..: bits of writable word signals (control words), same scheme

``layout: flat`` puts everything in one unit (``flat_unit_id``): the gateway block at 0 and node
*k* (1-based, config order) at ``k * flat_stride``, with the same offsets inside each block.

Imports: config, profiles, objref. Never pymodbus, bus/, zenoh_bridge/.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from typing import Literal

from gateway.config import Config
from gateway.profiles import load_profile
from gateway.profiles.derived import text_signals

Table = Literal["ir", "hr", "di", "co"]
TABLE_NAMES = {"ir": "input register", "hr": "holding register", "di": "discrete input", "co": "coil"}

SIGNAL_BASE = 100
NMT_REGISTER = 0

#: node diagnostics in input registers: (offset, name, type, description)
NODE_DIAG = [
    (0, "quality", "uint16", "0 good, 1 stale, 2 bad (never received / node not operational)"),
    (1, "nmt_state", "uint16", "NMT state: 0 boot-up, 4 stopped, 5 operational, 127 pre-op, 65535 unknown"),
    (2, "alive", "uint16", "1 while heartbeat / node guarding is OK"),
    (3, "lifecycle", "uint16", "0 waiting, 1 booting, 2 configuring, 3 operational, 4 lost"),
    (4, "data_age_ms", "uint32", "ms since the last process data frame (4294967295 = never)"),
    (6, "last_emcy_code", "uint16", "last EMCY error code (0 = none / reset)"),
    (7, "last_emcy_register", "uint16", "error register (1001h) of the last EMCY"),
    (8, "emcy_count", "uint16", "EMCY messages received"),
    (9, "loss_count", "uint16", "heartbeat / guarding losses"),
    (10, "link_state", "uint16", "guarding-bit link: 0 not used, 1 ok, 2 fault, 3 unknown"),
    (11, "link_fault_count", "uint16", "guarding-bit link faults"),
    (12, "last_sdo_abort", "uint32", "last SDO abort code (e.g. 0x06090011)"),
    (14, "boot_count", "uint16", "boot-ups seen"),
    (15, "pdo_errors", "uint16", "PDOs with unexpected length"),
]  # fmt: skip
NODE_DIAG_BITS = [
    (0, "alive", "heartbeat / guarding OK"),
    (1, "operational", "alive, NMT operational and process-data link OK"),
    (2, "link_ok", "guarding-bit link OK (or not used)"),
    (3, "error_active", "an EMCY error is active"),
]
GATEWAY_REGS = [
    (0, "bus_state", "uint16", "CAN bus: 0 down, 1 ok, 2 error passive / bus off"),
    (1, "frames_in", "uint32", "CAN frames received"),
    (3, "frames_out", "uint32", "CAN frames sent"),
    (5, "decode_errors", "uint32", "frames that could not be decoded"),
    (7, "unknown_cob_id", "uint32", "frames with an unexpected COB-ID"),
    (9, "bus_errors", "uint32", "CAN bus errors"),
    (11, "uptime_s", "uint32", "seconds since start"),
    (13, "version_major", "uint16", "gateway version"),
    (14, "version_minor", "uint16", ""),
    (15, "version_patch", "uint16", ""),
    (16, "nodes_configured", "uint16", "nodes in the configuration"),
    (17, "nodes_alive", "uint16", "nodes alive"),
    (18, "nodes_operational", "uint16", "nodes operational"),
]

_REG_TYPE = {
    "bool": "uint16", "int8": "int16", "uint8": "uint16", "int16": "int16", "uint16": "uint16",
    "int24": "int32", "uint24": "uint32", "int32": "int32", "uint32": "uint32", "int64": "int64",
    "uint64": "uint64", "float32": "float32", "string": "string", "bytes": "string",
}  # fmt: skip
_REG_COUNT = {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2, "int64": 4, "uint64": 4}


class RegisterMapError(Exception):
    def __init__(self, key: str, msg: str):
        self.key = key
        super().__init__(msg)


@dataclass(frozen=True)
class Point:
    unit: int
    table: Table
    address: int
    count: int  # registers (1 for a bit)
    kind: Literal["signal", "bit", "diag", "diag_bit", "nmt", "gateway"]
    name: str  # signal / diagnostic name
    type: str  # register type: int16, uint16, int32, uint32, float32, int64, uint64, string, bool
    access: Literal["ro", "rw"]
    node: str | None = None
    bit: int | None = None
    word_order: Literal["big", "little"] = "big"
    scale: float = 1.0
    offset: float = 0.0
    engineering: bool = False
    unit_text: str = ""
    transport: Literal["pdo", "sdo", "diag"] = "diag"
    description: str = ""

    @property
    def end(self) -> int:
        return self.address + self.count

    @property
    def scaling(self) -> str:
        if self.engineering:
            return f"float32 = raw x {self.scale:g} + {self.offset:g}"
        if self.scale != 1.0 or self.offset:
            return f"value x {self.scale:g} + {self.offset:g}"
        return ""


@dataclass
class RegisterMap:
    points: list[Point] = field(default_factory=list)
    #: (unit, table) -> {address: point} for every address a point covers
    index: dict[tuple[int, Table], dict[int, Point]] = field(default_factory=dict)
    units: dict[int, str | None] = field(default_factory=dict)  # unit -> node name (None: gateway)

    def add(self, p: Point, key: str) -> None:
        idx = self.index.setdefault((p.unit, p.table), {})
        for a in range(p.address, p.end):
            other = idx.get(a)
            if other is not None:
                where = f"{other.node}.{other.name}" if other.node else other.name
                raise RegisterMapError(
                    key,
                    f"{TABLE_NAMES[p.table]} {a} of unit {p.unit} is used twice: "
                    f"{p.node}.{p.name} and {where}",
                )
            if a > 0xFFFF:
                raise RegisterMapError(key, f"address {a} of {p.node}.{p.name} is beyond 65535")
            idx[a] = p
        self.points.append(p)

    def lookup(self, unit: int, table: Table, address: int) -> Point | None:
        return self.index.get((unit, table), {}).get(address)

    # ------------------------------------------------------------------ rendering
    HEADER = ["unit", "table", "address", "type", "access", "node", "signal", "unit_of_measure", "scaling", "description"]  # fmt: skip

    def rows(self) -> list[list[str]]:
        out = []
        order = {"ir": 0, "hr": 1, "di": 2, "co": 3}
        for p in sorted(self.points, key=lambda p: (p.unit, order[p.table], p.address)):
            name = p.name if p.bit is None or p.kind == "diag_bit" else f"{p.name}.bit{p.bit}"
            typ = p.type if p.type != "string" else f"string[{p.count * 2}]"
            if p.kind in ("signal",) and p.count > 1 and p.type != "string":
                typ += f" ({p.word_order} word first)" if p.word_order == "little" else ""
            out.append(
                [
                    str(p.unit),
                    TABLE_NAMES[p.table],
                    str(p.address) if p.count == 1 else f"{p.address}-{p.end - 1}",
                    typ,
                    p.access,
                    p.node or "(gateway)",
                    name,
                    p.unit_text,
                    p.scaling,
                    p.description,
                ]
            )
        return out

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.HEADER)
        w.writerows(self.rows())
        return buf.getvalue()

    def to_markdown(self) -> str:
        lines = ["| " + " | ".join(self.HEADER) + " |", "|" + "---|" * len(self.HEADER)]
        for r in self.rows():
            lines.append("| " + " | ".join(c.replace("|", "\\|") for c in r) + " |")
        return "\n".join(lines) + "\n"


def build_register_map(cfg: Config) -> RegisterMap:
    rm = RegisterMap()
    flat = cfg.modbus.layout == "flat"
    stride = cfg.modbus.flat_stride
    gw_unit = cfg.modbus.flat_unit_id if flat else cfg.modbus.gateway_unit_id
    rm.units[gw_unit] = None
    for off, name, typ, desc in GATEWAY_REGS:
        rm.add(
            Point(gw_unit, "ir", off, _REG_COUNT[typ], "gateway", name, typ, "ro", description=desc),
            "modbus",
        )
    for k, ncfg in enumerate(cfg.nodes, start=1):
        key = f"nodes[{k - 1}]"
        lp = load_profile(ncfg.profile, cfg.base_dir)
        if flat:
            unit, base = cfg.modbus.flat_unit_id, k * stride
        else:
            unit = ncfg.modbus.unit_id or ncfg.node_id
            base = 0
            rm.units[unit] = ncfg.name
        limit = base + stride if flat else 0x10000

        def add(p: Point, key: str = key, base: int = base, limit: int = limit, node: str = ncfg.name) -> None:
            if p.end > limit:
                raise RegisterMapError(
                    "modbus.flat_stride",
                    f"node {node} needs addresses up to {p.end - base} in its block, "
                    f"more than flat_stride {stride}",
                )
            rm.add(p, key)

        n = ncfg.name
        for off, name, typ, desc in NODE_DIAG:
            add(Point(unit, "ir", base + off, _REG_COUNT[typ], "diag", name, typ, "ro", n, description=desc))  # fmt: skip
        for off, name, desc in NODE_DIAG_BITS:
            add(Point(unit, "di", base + off, 1, "diag_bit", name, "bool", "ro", n, bit=off, description=desc))  # fmt: skip
        add(Point(unit, "hr", base + NMT_REGISTER, 1, "nmt", "nmt_command", "uint16", "rw", n,
                  description="write 1 start, 2 stop, 128 pre-op, 129 reset node, 130 reset comm; reads NMT state"))  # fmt: skip
        next_addr = {"ir": base + SIGNAL_BASE, "hr": base + SIGNAL_BASE}
        next_bit = {"di": base + SIGNAL_BASE, "co": base + SIGNAL_BASE}
        for sig in lp.profile.signals:
            ov = ncfg.signals.get(sig.name)
            skey = f"{key}.signals.{sig.name}" if ov else key
            writable = sig.access in ("rw", "wo")
            table: Table = "hr" if (writable or sig.transport == "sdo") else "ir"
            rtype = _REG_TYPE[sig.type]
            scale = ov.scale if ov and ov.scale is not None else sig.scale
            offset = ov.offset if ov and ov.offset is not None else sig.offset
            engineering = bool(ov and ov.as_float) and rtype != "string"
            if engineering:
                rtype = "float32"
            count = ((sig.length or 0) + 1) // 2 if rtype == "string" else _REG_COUNT[rtype]
            word_order = (ov.word_order if ov and ov.word_order else None) or cfg.modbus.word_order
            if ov is not None and ov.address is not None:
                addr = base + ov.address
            else:
                addr = next_addr[table]
                next_addr[table] = addr + count
            add(
                Point(
                    unit,
                    table,
                    addr,
                    count,
                    "signal",
                    sig.name,
                    rtype,
                    "rw" if writable else "ro",
                    n,
                    word_order=word_order,
                    scale=scale,
                    offset=offset,
                    engineering=engineering,
                    unit_text=(ov.unit if ov and ov.unit is not None else sig.unit),
                    transport=sig.transport,
                    description=sig.description,
                ),
                skey,
            )
            if sig.bits and sig.type not in ("string", "bytes", "float32"):
                btable: Table = "co" if writable and sig.transport == "pdo" else "di"
                width = sig.bit_length
                start = next_bit[btable]
                next_bit[btable] = start + width
                named = {}
                for bf in sig.bits:
                    for b in range(bf.bit, bf.bit + bf.width):
                        named[b] = bf
                for b in range(width):
                    bf = named.get(b)
                    desc = bf.description if bf else "(reserved)"
                    bname = bf.name if bf else f"bit{b}"
                    add(
                        Point(
                            unit,
                            btable,
                            start + b,
                            1,
                            "bit",
                            sig.name,
                            "bool",
                            "rw" if btable == "co" else "ro",
                            n,
                            bit=b,
                            transport=sig.transport,
                            description=f"{bname}: {desc}" if desc else bname,
                        ),
                        key,
                    )
        for ts in text_signals(lp.profile):
            # AP05 alpha-numeric rows as one string point each (profiles/derived.py)
            count = (ts.length + 1) // 2
            addr = next_addr["hr"]
            next_addr["hr"] = addr + count
            head = lp.profile.signal(ts.head)
            add(
                Point(unit, "hr", addr, count, "signal", ts.name, "string", "rw", n,
                      transport="pdo", description=ts.as_signal(head).description)
            )  # fmt: skip
    return rm
