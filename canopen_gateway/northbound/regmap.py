"""The Modbus register map, compiled from profiles + config (pure: no I/O, no pymodbus).

Layout (``modbus.layout: per_node``, the default): one unit id per node (default its node id)
and one for the gateway itself (``modbus.gateway_unit_id``, default 247). Within a node's unit:

* input registers 0..15: diagnostics (``NODE_DIAG``: quality, NMT state, alive, data age, EMCY,
  losses, guarding-bit link, last SDO abort)
* input registers 100..: process data read from the node (the TPDO signals of the node's PDO
  layout), in profile order; an object that a TPDO and an RPDO both carry is here (the
  device's value) and in the holding registers (the output)
* holding register 0: NMT command (write 1 start, 2 stop, 128 pre-op, 129 reset, 130 reset comm;
  reads the NMT state)
* holding registers 100..: writable process data (RPDO signals), then configuration objects
  served by SDO, in profile order
* discrete inputs 0..4: alive, operational, link ok, error active, outputs safe; 100..: the bits of read-only
  word signals that name single bits, one address per bit of the word: address = start + bit
* coils 100..: the bits of writable word signals (control words, SDO parameter words), same
  scheme

A signal of the profile sent by PDO but not mapped in the node's PDO layout (e.g. POSI+ speed
outside PDO type 2) has no register. ``nodes[].signals.<name>`` overrides pin an address
(relative to the node's block), serve a value as engineering float32 (``as_float``), or change
the word order of one point.

``layout: flat`` puts everything in one unit (``flat_unit_id``): the gateway block at 0 and node
*k* (1-based, config order) at ``k * flat_stride``, with the same offsets inside each block.

The gateway's own registers (unit 247) are ``northbound.gateway_block``'s.

Imports: config, profiles, device.resolved, northbound.scaling, northbound.gateway_block.
Never pymodbus, zenoh_bridge/.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field, replace
from typing import Literal

from canopen_gateway.config import Config, NodeConfig
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.northbound.gateway_block import gateway_registers
from canopen_gateway.northbound.scaling import scaled, unscaled_step
from canopen_gateway.profiles import LoadedProfile
from canopen_gateway.profiles.derived import text_signals
from canopen_gateway.profiles.layout import tpdo_objects
from canopen_gateway.profiles.schema import Signal

Table = Literal["ir", "hr", "di", "co"]
TABLE_NAMES = {
    "ir": "input register",
    "hr": "holding register",
    "di": "discrete input",
    "co": "coil",
}
TABLE_ORDER = {"ir": 0, "hr": 1, "di": 2, "co": 3}

SIGNAL_BASE = 100
NMT_REGISTER = 0

#: node diagnostics in input registers: (offset, name, type, description)
NODE_DIAG = [
    (0, "quality", "uint16", "worst quality of the node's process data: 0 good, 1 stale (node lost, not operational, link fault or data older than stale_after_ms), 2 bad (never received, flagged invalid by the device, or nothing to serve: the node's PDOs map nothing)"),
    (1, "nmt_state", "uint16", "NMT state: 0 boot-up, 4 stopped, 5 operational, 127 pre-operational, 65535 unknown"),
    (2, "alive", "uint16", "1 while heartbeat / node guarding is OK"),
    (3, "lifecycle", "uint16", "0 waiting (never seen, or lost: waiting for boot-up), 1 booting, 2 configuring, 3 operational, 4 unknown (a pair's standby: the node not heard started)"),
    (4, "data_age_ms", "uint32", "ms since the last process data frame (4294967295 = never)"),
    (6, "last_emcy_code", "uint16", "last EMCY error code (0 = none / reset)"),
    (7, "last_emcy_register", "uint16", "error register (1001h) of the last EMCY"),
    (8, "emcy_count", "uint16", "EMCY messages received"),
    (9, "loss_count", "uint16", "heartbeat / guarding losses"),
    (10, "link_state", "uint16", "guarding-bit link: 0 not used, 1 ok, 2 fault, 3 unknown"),
    (11, "link_fault_count", "uint16", "guarding-bit link faults"),
    (12, "last_sdo_abort", "uint32", "abort code of the last SDO transfer the node aborted (e.g. 0x06090011), 0 = none"),
    (14, "boot_count", "uint16", "boot-ups seen"),
    (15, "pdo_errors", "uint16", "PDOs with unexpected length"),
]  # fmt: skip
NODE_DIAG_BITS = [
    (0, "alive", "heartbeat / guarding OK"),
    (1, "operational", "alive, NMT operational and process-data link OK"),
    (2, "link_ok", "guarding-bit link OK (or not used)"),
    (3, "error_active", "an EMCY error is active"),
    (4, "outputs_safe", "the node's outputs hold the safe values of the output watchdog"),
]
NMT_DESCRIPTION = (
    "write 1 start, 2 stop, 128 pre-operational, 129 reset node, 130 reset communication; "
    "reads the NMT state"
)

_REG_TYPE = {
    "bool": "uint16", "int8": "int16", "uint8": "uint16", "int16": "int16", "uint16": "uint16",
    "int24": "int32", "uint24": "uint32", "int32": "int32", "uint32": "uint32", "int64": "int64",
    "uint64": "uint64", "float32": "float32", "string": "string", "bytes": "string",
    "int40": "int64", "int48": "int64", "int56": "int64", "uint40": "uint64", "uint48": "uint64",
    "uint56": "uint64", "float64": "float64",
    # CiA 301 7.1.6.5/6 (docs/modbus.md): Unix milliseconds / milliseconds as uint64
    "time_of_day": "time_of_day", "time_difference": "time_difference",
}  # fmt: skip
_REG_COUNT = {
    "int16": 1,
    "uint16": 1,
    "int32": 2,
    "uint32": 2,
    "float32": 2,
    "int64": 4,
    "uint64": 4,
    "float64": 4,
    "time_of_day": 4,
    "time_difference": 4,
}
#: what the registers of a time type hold (``Point.type_text``)
_TIME_TEXT = {"time_of_day": "Unix ms", "time_difference": "ms"}


class RegisterMapError(Exception):
    def __init__(self, key: str, msg: str):
        self.key = key
        super().__init__(msg)


@dataclass(frozen=True)
class Point:
    """One addressable item: a register value (1..n registers) or one bit."""

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
    network: str | None = None  # the CAN network of a gateway point that is one network's

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

    @property
    def type_text(self) -> str:
        if self.type == "string":
            return f"string[{self.count * 2}]"
        if self.count > 1:
            first = "high" if self.word_order == "big" else "low"
            if self.type in _TIME_TEXT:
                return f"{self.type} ({_TIME_TEXT[self.type]} as uint64, {first} word first)"
            return f"{self.type} ({first} word first)"
        return self.type


@dataclass
class RegisterMap:
    points: list[Point] = field(default_factory=list)
    #: (unit, table) -> {address: point} for every address a point covers
    index: dict[tuple[int, Table], dict[int, Point]] = field(default_factory=dict)
    units: dict[int, str | None] = field(default_factory=dict)  # unit -> node name (None: gateway)
    networks: dict[str, str] = field(default_factory=dict)  # node name -> its CAN network
    several_networks: bool = False  # the Markdown table shows the network column
    #: the config key that placed each point (a clash names both keys)
    keys: dict[Point, str] = field(default_factory=dict, repr=False)

    def add(self, p: Point, key: str) -> None:
        idx = self.index.setdefault((p.unit, p.table), {})
        for a in range(p.address, p.end):
            other = idx.get(a)
            if other is not None:
                where = f"{other.node}.{other.name}" if other.node else other.name
                placed = self.keys.get(other)
                raise RegisterMapError(
                    key,
                    f"{TABLE_NAMES[p.table]} {a} of unit {p.unit} is used twice: "
                    f"{p.node}.{p.name} ({key}) and {where}" + (f" ({placed})" if placed else ""),
                )
            if a > 0xFFFF:
                raise RegisterMapError(key, f"address {a} of {p.node}.{p.name} is beyond 65535")
            idx[a] = p
        self.points.append(p)
        self.keys[p] = key

    def lookup(self, unit: int, table: Table, address: int) -> Point | None:
        return self.index.get((unit, table), {}).get(address)

    def only_unit(self, unit: int) -> RegisterMap:
        """The points of one unit id (a listing of one device)."""
        return RegisterMap(
            [p for p in self.points if p.unit == unit], {}, {unit: self.units.get(unit)},
            networks=self.networks, several_networks=self.several_networks,
        )  # fmt: skip

    def node_points(self, node: str) -> list[Point]:
        return [p for p in self.points if p.node == node]

    # ------------------------------------------------------------------ rendering
    HEADER = ["unit_id", "table", "address", "type", "access", "node", "signal", "unit", "scaling", "description"]  # fmt: skip

    def sorted_points(self) -> list[Point]:
        """Every point by unit, table (input, holding, discrete input, coil) and address."""
        return sorted(self.points, key=lambda p: (p.unit, TABLE_ORDER[p.table], p.address))

    @staticmethod
    def _row(p: Point, address: str, name: str, description: str) -> list[str]:
        """A row of the Markdown table (the CSV adds the point's network, ``network_of``)."""
        return [
            str(p.unit),
            TABLE_NAMES[p.table],
            address,
            p.type_text,
            p.access,
            p.node or "(gateway)",
            name,
            p.unit_text,
            p.scaling,
            description,
        ]

    def rows(self) -> list[list[str]]:
        """One row per point: every register value and every single bit (the CSV)."""
        out = []
        for p in self.sorted_points():
            name = p.name if p.kind != "bit" else f"{p.name}.bit{p.bit}"
            address = str(p.address) if p.count == 1 else f"{p.address}-{p.end - 1}"
            out.append(self._row(p, address, name, p.description))
        return out

    def grouped_rows(self) -> list[list[str]]:
        """Like ``rows`` but the bits of one word in one row (the Markdown table)."""
        return [row for _, row in self._grouped()]

    def _grouped(self) -> list[tuple[Point, list[str]]]:
        """``grouped_rows`` with the (first) point of each row."""
        out: list[tuple[Point, list[str]]] = []
        pts = self.sorted_points()
        i = 0
        while i < len(pts):
            p = pts[i]
            if p.kind != "bit":
                out.append((p, self.rows_of(p)))
                i += 1
                continue
            j = i
            while (
                j + 1 < len(pts)
                and pts[j + 1].kind == "bit"
                and (pts[j + 1].unit, pts[j + 1].table, pts[j + 1].node, pts[j + 1].name)
                == (p.unit, p.table, p.node, p.name)
                and pts[j + 1].address == pts[j].address + 1
            ):
                j += 1
            group = pts[i : j + 1]
            named = [
                f"{b.bit} {b.description}" for b in group if not b.description.startswith("(bit ")
            ]
            desc = f"address = {p.address} + bit; " + "; ".join(named)
            out.append(
                (p, [
                    str(p.unit),
                    TABLE_NAMES[p.table],
                    f"{p.address}-{group[-1].address}",
                    f"bits[{len(group)}]",
                    p.access,
                    p.node or "(gateway)",
                    p.name,
                    "",
                    "",
                    desc,
                ])
            )  # fmt: skip
            i = j + 1
        return out

    def rows_of(self, p: Point) -> list[str]:
        address = str(p.address) if p.count == 1 else f"{p.address}-{p.end - 1}"
        return self._row(p, address, p.name, p.description)

    def network_of(self, p: Point) -> str:
        """The CAN network a point is of: its node's, a network's gateway register's, or none
        (the gateway's own registers)."""
        return p.network or (self.networks.get(p.node, "") if p.node else "")

    def to_csv(self) -> str:
        """Every point, with the ``network`` column last (after ``HEADER``)."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow([*self.HEADER, "network"])
        w.writerows(
            [*row, self.network_of(p)] for p, row in zip(self.sorted_points(), self.rows(), strict=True)
        )
        return buf.getvalue()

    def to_markdown(self) -> str:
        """The grouped rows; with several networks, the ``network`` column last."""
        header = [*self.HEADER, "network"] if self.several_networks else self.HEADER
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for p, r in self._grouped():
            if self.several_networks:
                r = [*r, self.network_of(p)]
            lines.append("| " + " | ".join(c.replace("|", "\\|") for c in r) + " |")
        return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- compiling
def _mapped_objects(lp: LoadedProfile, variant: int | None) -> set[object]:
    """Objects carried by the node's PDO layout (default or the configured variant)."""
    tpdos, rpdos = lp.profile.layout(variant)
    return {e.object for p in (*tpdos, *rpdos) for e in p.mapping}


def _description(sig: Signal, scale: float, offset: float, engineering: bool) -> str:
    """The profile's description, value texts and the range a client may write, in register
    units: raw device values, or the engineering value of an ``as_float`` point."""
    desc = " ".join(sig.description.split())
    extra = []
    if sig.values:
        extra.append(
            "Values: " + ", ".join(f"{k} {v}" for k, v in sorted(sig.values.items())) + "."
        )
    if sig.access != "ro" and (sig.min is not None or sig.max is not None):

        def shown(eng: float | None) -> str:
            if eng is None:
                return ""
            raw = unscaled_step(eng, sig.scale, sig.offset)
            return f"{scaled(raw, scale, offset):g}" if engineering else str(raw)

        extra.append(f"Range {shown(sig.min)}..{shown(sig.max)}.")
    return " ".join([desc, *extra]).strip()


def _bit_descriptions(sig: Signal) -> dict[int, str] | None:
    """Bit number -> description for a word with single named bits; None: no bit points."""
    single = [bf for bf in sig.bits if bf.width == 1]
    if not single or sig.type in ("string", "bytes", "float32"):
        return None
    names: dict[int, list[str]] = {}
    texts: dict[int, list[str]] = {}
    for bf in single:
        names.setdefault(bf.bit, []).append(bf.name)
        if bf.description:
            texts.setdefault(bf.bit, []).append(bf.description)
    out = {}
    for bit, ns in names.items():
        label = " / ".join(ns)
        text = " / ".join(texts.get(bit, []))
        out[bit] = f"{label}: {text}" if text else label
    return out


def build_register_map(cfg: Config, nodes: dict[str, ResolvedNode]) -> RegisterMap:
    """The gateway's registers, then per node (in config order) its block: diagnostics, NMT,
    signals (with their bits), the derived text rows."""
    rm = RegisterMap()
    flat = cfg.modbus.layout == "flat"
    gw_unit = cfg.modbus.flat_unit_id if flat else cfg.modbus.gateway_unit_id
    rm.units[gw_unit] = None
    names = cfg.network_names()
    rm.several_networks = len(names) > 1
    for off, name, typ, desc, network in gateway_registers(names):
        rm.add(
            Point(
                gw_unit, "ir", off, _REG_COUNT[typ], "gateway", name, typ, "ro", description=desc,
                network=network,
            ),
            "modbus" if network is None else "networks",
        )  # fmt: skip
    for k, ncfg in enumerate(cfg.nodes, start=1):
        rm.networks[ncfg.name] = cfg.network_of(ncfg.name)
        _add_node(rm, cfg, ncfg, nodes[ncfg.name].lp, k)
    return rm


@dataclass
class _Block:
    """One node's block of registers being laid out: its unit, base address and limit, the
    config key of its points and the next free address of each table."""

    rm: RegisterMap
    unit: int
    base: int
    limit: int
    stride: int
    key: str
    node: str
    #: each table's addresses start at the block's SIGNAL_BASE
    next_addr: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        self.next_addr = {t: self.base + SIGNAL_BASE for t in ("ir", "hr", "di", "co")}

    def add(self, p: Point, key: str | None = None) -> None:
        if p.end > self.limit:
            raise RegisterMapError(
                "modbus.flat_stride",
                f"node {self.node} needs addresses up to {p.end - self.base} in its block, "
                f"more than flat_stride {self.stride}",
            )
        self.rm.add(p, self.key if key is None else key)

    def take(self, table: str, count: int) -> int:
        """The next free address of ``table`` for ``count`` registers (or bits)."""
        addr = self.next_addr[table]
        self.next_addr[table] = addr + count
        return addr


def _add_node(rm: RegisterMap, cfg: Config, ncfg: NodeConfig, lp: LoadedProfile, k: int) -> None:
    """The ``k``-th node's block: diagnostics, NMT register, signals, text rows."""
    flat = cfg.modbus.layout == "flat"
    stride = cfg.modbus.flat_stride
    if flat:
        unit, base = cfg.modbus.flat_unit_id, k * stride
    else:
        unit = ncfg.modbus.unit_id or ncfg.node_id
        base = 0
        rm.units[unit] = ncfg.name
    limit = base + stride if flat else 0x10000
    blk = _Block(rm, unit, base, limit, stride, f"nodes[{k - 1}]", ncfg.name)
    n = ncfg.name
    for off, name, typ, desc in NODE_DIAG:
        blk.add(Point(unit, "ir", base + off, _REG_COUNT[typ], "diag", name, typ, "ro", n, description=desc))  # fmt: skip
    for off, name, desc in NODE_DIAG_BITS:
        blk.add(Point(unit, "di", base + off, 1, "diag_bit", name, "bool", "ro", n, bit=off, description=desc))  # fmt: skip
    blk.add(Point(unit, "hr", base + NMT_REGISTER, 1, "nmt", "nmt_command", "uint16", "rw", n, description=NMT_DESCRIPTION))  # fmt: skip
    mapped = _mapped_objects(lp, ncfg.pdo_variant)
    inputs = tpdo_objects(lp.profile, ncfg.pdo_variant)
    for sig in lp.profile.signals:
        if sig.transport == "pdo" and sig.object not in mapped:
            continue
        _add_signal(blk, cfg, ncfg, sig, sig.transport == "pdo" and sig.object in inputs)
    for ts in text_signals(lp.profile):
        # AP05 alpha-numeric rows as one string point each (profiles/derived.py)
        count = (ts.length + 1) // 2
        addr = blk.take("hr", count)
        head = lp.profile.signal(ts.head)
        blk.add(
            Point(unit, "hr", addr, count, "signal", ts.name, "string", "rw", n,
                  transport="pdo", description=ts.as_signal(head).description)
        )  # fmt: skip


def _add_signal(blk: _Block, cfg: Config, ncfg: NodeConfig, sig: Signal, in_tpdo: bool) -> None:
    """One signal's point (and its read-only twin when an output is in a TPDO too), then its
    bits; the node's ``signals:`` overrides applied."""
    key = blk.key
    ov = ncfg.signals.get(sig.name)
    skey = f"{key}.signals.{sig.name}" if ov else key
    writable = sig.access in ("rw", "wo")
    table: Table = "hr" if (writable or sig.transport == "sdo") else "ir"
    rtype = _REG_TYPE[sig.type_name]
    scale = ov.scale if ov and ov.scale is not None else sig.scale
    offset = ov.offset if ov and ov.offset is not None else sig.offset
    engineering = bool(ov and ov.as_float) and rtype != "string"
    if engineering and rtype in _TIME_TEXT:
        raise RegisterMapError(
            f"{key}.signals.{sig.name}.as_float",
            f"{sig.name} is a {rtype}: as_float applies to numbers only",
        )
    if engineering:
        rtype = "float32"
    count = ((sig.length or 0) + 1) // 2 if rtype == "string" else _REG_COUNT[rtype]
    word_order = (ov.word_order if ov and ov.word_order else None) or cfg.modbus.word_order
    if ov is not None and ov.address is not None:
        addr = blk.base + ov.address
    else:
        addr = blk.take(table, count)
    point = Point(
        blk.unit,
        table,
        addr,
        count,
        "signal",
        sig.name,
        rtype,
        "rw" if writable else "ro",
        blk.node,
        word_order=word_order,
        scale=scale,
        offset=offset,
        engineering=engineering,
        unit_text=(ov.unit if ov and ov.unit is not None else sig.unit),
        transport=sig.transport_name,
        description=_description(sig, scale, offset, engineering),
    )
    blk.add(point, skey)
    if table == "hr" and in_tpdo:
        # in a TPDO too: the device's own value, read-only, beside the output
        addr = blk.take("ir", count)
        desc = f"(the device's value, by TPDO; the output is holding register {point.address})"
        desc = f"{point.description} {desc}".lstrip()
        blk.add(replace(point, table="ir", address=addr, access="ro", description=desc), skey)
    bits = _bit_descriptions(sig)
    if bits is None:
        return
    btable: Table = "co" if writable else "di"
    width = sig.bit_length
    start = blk.take(btable, width)
    for b in range(width):
        blk.add(
            Point(blk.unit, btable, start + b, 1, "bit", sig.name, "bool",
                  "rw" if writable else "ro", blk.node, bit=b, transport=sig.transport_name,
                  description=bits.get(b, f"(bit {b} not used)")),
        )  # fmt: skip
