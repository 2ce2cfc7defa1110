"""Schema of a device profile file (``canopen_gateway/profiles/<family>.yaml``).

A profile is an *overlay* on a device's EDS (the complete object dictionary): names, units,
scaling, bit names and value texts of signals, PDO layouts where the EDS mapping objects do not
describe them (and their documented variants), EMCY texts, factory settings, what the gateway
configures at boot, value constraints the EDS cannot express, and the *features* code may key
behaviour on. What the EDS already says is not repeated: a signal's ``type``, ``access`` and
``transport`` default to what the EDS and the PDO layout say (filled in by the loader), and a
profile without ``tpdos``/``rpdos`` takes the PDO layout of the EDS. Adding a device needs no
code; an EDS alone is enough (``nodes[].eds``), a profile adds names and behaviour.

This module knows the shape of a profile only; it imports nothing from the rest of the gateway
but ``canopen_gateway.canopen.objref``.

Imports: canopen.objref.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, PlainSerializer, model_validator

from canopen_gateway.canopen.objref import ObjRef


def _parse_obj(v: Any) -> ObjRef:
    if isinstance(v, (list, tuple)) and len(v) == 2:
        return ObjRef(int(v[0]), int(v[1]))
    return ObjRef.parse(v)


Obj = Annotated[ObjRef, BeforeValidator(_parse_obj), PlainSerializer(str)]


def _parse_int(v: Any) -> int:
    """Accept 1234, "0x4D2", "4D2h" for numbers copied from a manual."""
    if isinstance(v, bool):
        raise ValueError("expected a number")
    if isinstance(v, int):
        return v
    if isinstance(v, str):
        s = v.strip().replace("_", "")
        if s.lower().endswith("h"):
            return int(s[:-1], 16)
        return int(s, 0)
    raise ValueError("expected a number")


HexInt = Annotated[int, BeforeValidator(_parse_int)]

#: Data types a signal may have; sizes in bits. ``string`` is ASCII (VISIBLE_STRING); the time
#: types hold the CiA 301 48-bit word (``canopen_gateway.canopen.cia301`` converts it).
SignalType = Literal[
    "bool",
    "int8",
    "uint8",
    "int16",
    "uint16",
    "int24",
    "uint24",
    "int32",
    "uint32",
    "int64",
    "uint64",
    "float32",
    "int40",
    "int48",
    "int56",
    "uint40",
    "uint48",
    "uint56",
    "float64",
    "time_of_day",
    "time_difference",
    "string",
    "bytes",
]

TYPE_BITS: dict[str, int] = {
    "bool": 1,
    "int8": 8,
    "uint8": 8,
    "int16": 16,
    "uint16": 16,
    "int24": 24,
    "uint24": 24,
    "int32": 32,
    "uint32": 32,
    "int64": 64,
    "uint64": 64,
    "float32": 32,
    "int40": 40,
    "int48": 48,
    "int56": 56,
    "uint40": 40,
    "uint48": 48,
    "uint56": 56,
    "float64": 64,
    "time_of_day": 48,  # CiA 301 7.1.6.5: the 48-bit word (ms and days)
    "time_difference": 48,  # CiA 301 7.1.6.6
}

#: Feature names that code may key behaviour on (never on a device name).
KNOWN_FEATURES = {
    "lss_slave",  # CiA 305 LSS slave (SGH10 manual 4.6)
    "guarding_bit",  # control-word bit echoed in status word (AP05 manual 5.5.5)
    "external_heartbeat",  # RPDO/SYNC watchdog object (AP05 manual 5.5.4, 5F09h)
    "auto_id",  # node id assignment by SDO to a sub-index (AP05 5F0Ah:02)
    "referencing",  # no valid position before referencing (MSK5000 5115h)
    "remappable_tpdo",  # TPDO mapping may be changed (MSK5000 4.3.1.2)
    "pdo_type_selector",  # PDO layout chosen by an object (BEI 2005h); see pdo_variants
    "work_areas",  # DS-406 work areas 6400h-6402h
    "cams",  # DS-406 cams 6300h-6320h
    "heartbeat_consumer",  # device consumes the master's heartbeat (1016h)
    "alphanumeric_display",  # ASCII set points (AP05 5F1Bh)
    "speed_alarm",  # speed limit alarm (MSK5000 5FFAh)
    "node_id_object",  # node id / baud rate by object + store + reset (BEI 2101h/2100h)
    "position_indicator",  # set points in, status word out (AP05 5F16h/5F0Ch/5F19h)
    "ds406_cycle_timer",  # DS-406: 6200h cyclic timer is 1800h:05 (SGH10 manual 4.7.2.31)
}

_NAME_RE = re.compile(r"^[a-z][a-z0-9_]*$")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class BitField(_Strict):
    """A named bit (or group of bits) of a word signal, e.g. AP05 status word bit 8."""

    bit: int = Field(ge=0, le=63, description="lowest bit number")
    width: int = Field(default=1, ge=1, le=32)
    name: str
    description: str = ""
    writable: bool = False  # a coil (only meaningful on a writable word signal)

    @model_validator(mode="after")
    def _name_ok(self) -> BitField:
        if not _NAME_RE.match(self.name):
            raise ValueError(f"bit name {self.name!r} must be snake_case")
        return self


class Signal(_Strict):
    """A named value of the device.

    ``transport: pdo`` signals are decoded from a TPDO (``access: ro``) or sent in an RPDO
    (``access: rw``/``wo``). ``transport: sdo`` signals are configuration objects read/written
    by SDO on request. Engineering value = raw * scale + offset.
    """

    name: str
    object: Obj
    type: SignalType | None = Field(default=None, description="default: the EDS DataType")
    access: Literal["ro", "rw", "wo"] | None = Field(
        default=None, description="default: rw when in an RPDO, ro in a TPDO, else the EDS AccessType"
    )
    transport: Literal["pdo", "sdo"] | None = Field(
        default=None, description="default: pdo when in a PDO layout, else sdo"
    )
    unit: str = ""
    scale: float = 1.0
    offset: float = 0.0
    length: int | None = Field(default=None, ge=1, le=255, description="bytes, for string/bytes")
    min: float | None = Field(default=None, description="lowest engineering value (raw x scale + offset)")
    max: float | None = Field(default=None, description="highest engineering value")
    values: dict[HexInt, str] = Field(default_factory=dict, description="value texts (enums)")
    bits: list[BitField] = Field(default_factory=list)
    description: str = ""
    safe_value: float | int | str | None = Field(
        default=None,
        description="raw value an RPDO output falls back to when the PLC is gone (modbus.watchdog_ms)",
    )

    @model_validator(mode="after")
    def _check(self) -> Signal:
        if not _NAME_RE.match(self.name):
            raise ValueError(f"signal name {self.name!r} must be snake_case")
        return self

    @property
    def type_name(self) -> SignalType:
        """The signal's type: the profile's, else the EDS DataType (the loader fills it in, so
        every signal of a loaded profile has one)."""
        if self.type is None:
            raise ValueError(f"signal {self.name}: no type (not resolved from the EDS)")
        return self.type

    @property
    def transport_name(self) -> Literal["pdo", "sdo"]:
        """``pdo`` or ``sdo`` (filled in by the loader from the PDO layout)."""
        if self.transport is None:
            raise ValueError(f"signal {self.name}: no transport (not resolved from the layout)")
        return self.transport

    @property
    def bit_length(self) -> int:
        if self.type in ("string", "bytes"):
            return 8 * (self.length or 0)
        return TYPE_BITS.get(self.type or "", 0)


class PdoEntry(_Strict):
    object: Obj
    bits: int = Field(ge=1, le=64)


def _parse_entry(v: Any) -> Any:
    """``"0x6004:00/32"`` -> {object: 0x6004:00, bits: 32}."""
    if isinstance(v, str):
        if "/" not in v:
            raise ValueError(f"PDO entry {v!r} must be 'index:sub/bits', e.g. '0x6004:00/32'")
        obj, bits = v.rsplit("/", 1)
        return {"object": obj, "bits": int(bits)}
    return v


class Pdo(_Strict):
    """One PDO: its number, COB-ID base, transmission and mapping (in byte order)."""

    number: int = Field(ge=1, le=512)
    cob_id: HexInt | None = Field(
        default=None, description="COB-ID without node id; default 0x180/0x280/.. by number"
    )
    add_node_id: bool = True
    transmission_type: int = Field(default=254, ge=0, le=255)
    event_timer_ms: int | None = Field(default=None, ge=0, le=65535)
    inhibit_time_100us: int | None = Field(default=None, ge=0, le=65535)
    sync_start: int | None = Field(default=None, ge=0, le=240)
    mapping: list[Annotated[PdoEntry, BeforeValidator(_parse_entry)]]
    description: str = ""
    origin: Literal["profile", "eds", "config"] = Field(
        default="profile", description="set by the loader: where this layout comes from"
    )

    @model_validator(mode="after")
    def _fits(self) -> Pdo:
        total = sum(e.bits for e in self.mapping)
        if total > 64:
            raise ValueError(f"PDO {self.number} maps {total} bits, more than 8 bytes")
        return self

    @property
    def length(self) -> int:
        return (sum(e.bits for e in self.mapping) + 7) // 8


class PdoVariant(_Strict):
    description: str = ""
    tpdos: list[Pdo] = Field(default_factory=list)
    rpdos: list[Pdo] = Field(default_factory=list)


class PdoVariants(_Strict):
    """PDO layouts chosen by the value of an object (BEI POSI+ 2005h)."""

    selector: Obj
    default: HexInt
    variants: dict[HexInt, PdoVariant]

    @model_validator(mode="after")
    def _default_exists(self) -> PdoVariants:
        if self.default not in self.variants:
            raise ValueError(f"default variant {self.default} is not one of {list(self.variants)}")
        return self


class BootWrite(_Strict):
    """One SDO download the gateway applies while configuring the node."""

    object: Obj
    value: HexInt | str
    type: SignalType | None = None
    note: str = ""


class Boot(_Strict):
    """What the gateway configures at boot by default (the node config may override)."""

    supervision: Literal["heartbeat", "guarding", "none"] = "heartbeat"
    heartbeat_ms: int = Field(default=100, ge=0, le=65535)
    guard_time_ms: int = Field(default=100, ge=0, le=65535)
    life_time_factor: int = Field(default=3, ge=0, le=255)
    sdo: list[BootWrite] = Field(default_factory=list)


class Factory(_Strict):
    node_id: int = Field(ge=1, le=127)
    bitrate_kbps: int | Literal["auto"]


_RANGE_RE = re.compile(r"^\s*(-?(?:0x[0-9a-f]+|\d+))\s*(?:\.\.\s*(-?(?:0x[0-9a-f]+|\d+)))?\s*$", re.I)


def parse_allowed(text: str) -> list[tuple[int, int]]:
    """``"0 or 10..65535"`` / ``"0, 10..65535"`` -> [(0, 0), (10, 65535)]."""
    out = []
    for part in re.split(r",|\bor\b", str(text)):
        if not part.strip():
            continue
        m = _RANGE_RE.match(part)
        if not m:
            raise ValueError(f"{text!r}: expected values and ranges like '0 or 10..65535'")
        lo = int(m.group(1), 0)
        hi = int(m.group(2), 0) if m.group(2) else lo
        if hi < lo:
            raise ValueError(f"{text!r}: range {lo}..{hi} is empty")
        out.append((lo, hi))
    if not out:
        raise ValueError(f"{text!r}: no values")
    return out


class Constraint(_Strict):
    """Values an object accepts beyond the EDS LowLimit/HighLimit, e.g. AP05 1017h "0 or
    10..65535" (a heartbeat time of 1..9 ms is refused by the device)."""

    allowed: str
    note: str = ""

    @model_validator(mode="after")
    def _parse(self) -> Constraint:
        parse_allowed(self.allowed)
        return self

    @property
    def ranges(self) -> list[tuple[int, int]]:
        return parse_allowed(self.allowed)

    def admits(self, value: int) -> bool:
        return any(lo <= value <= hi for lo, hi in self.ranges)


def _constraint(v: Any) -> Any:
    return {"allowed": str(v)} if isinstance(v, (str, int)) else v


class Profile(_Strict):
    """A device profile file: an overlay on the device's EDS."""

    family: str
    title: str = ""
    manual: str = Field(default="", description="the manual(s) this follows, e.g. '000, 003'")
    eds: str | None = Field(
        default=None, description="EDS file name, relative to the profile file (or nodes[].eds)"
    )
    vendor: str = ""
    device_type: HexInt | None = Field(default=None, description="expected 1000h value")
    factory: Factory | None = None
    verify_mapping: bool | None = Field(
        default=None,
        description="false: the mapping objects do not describe the layout in use (never "
        "verified); true: verified at boot by default; unset: per node",
    )
    rpdo_only_writable: list[Obj] = Field(
        default_factory=list,
        description="objects the EDS marks ro (SDO writes refused) that the device takes from an RPDO",
    )
    constraints: dict[Obj, Annotated[Constraint, BeforeValidator(_constraint)]] = Field(
        default_factory=dict, description="values objects accept beyond the EDS limits"
    )
    features: dict[str, dict[str, Any]] = Field(default_factory=dict)
    signals: list[Signal]
    tpdos: list[Pdo] = Field(default_factory=list)
    rpdos: list[Pdo] = Field(default_factory=list)
    pdo_variants: PdoVariants | None = None
    emcy: dict[HexInt, str] = Field(default_factory=dict)
    boot: Boot = Field(default_factory=Boot)
    notes: list[str] = Field(default_factory=list, description="manual inconsistencies and choices")
    sim: dict[str, Any] = Field(
        default_factory=dict, description="hints for the simulator (motion, position object...)"
    )

    @model_validator(mode="after")
    def _check(self) -> Profile:
        names = [s.name for s in self.signals]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"duplicate signal names: {sorted(dup)}")
        unknown = set(self.features) - KNOWN_FEATURES
        if unknown:
            raise ValueError(f"unknown features {sorted(unknown)}; known: {sorted(KNOWN_FEATURES)}")
        if "pdo_type_selector" in self.features and self.pdo_variants is None:
            raise ValueError("feature pdo_type_selector needs pdo_variants")
        return self

    def signal(self, name: str) -> Signal:
        for s in self.signals:
            if s.name == name:
                return s
        raise KeyError(name)

    def signal_for(self, obj: ObjRef) -> Signal | None:
        for s in self.signals:
            if s.object == obj:
                return s
        return None

    def layout(self, variant: int | None = None) -> tuple[list[Pdo], list[Pdo]]:
        """TPDOs and RPDOs of the default layout, or of the given ``pdo_variants`` value."""
        if self.pdo_variants is None:
            return list(self.tpdos), list(self.rpdos)
        v = self.pdo_variants.variants.get(
            self.pdo_variants.default if variant is None else variant
        )
        if v is None:
            raise KeyError(f"no PDO variant {variant}")
        return (list(v.tpdos) or list(self.tpdos)), (list(v.rpdos) or list(self.rpdos))


def default_cob_id(kind: Literal["tpdo", "rpdo"], number: int) -> int:
    """DS-301 pre-defined connection set: TPDO1..4 0x180..0x480, RPDO1..4 0x200..0x500."""
    if number > 4:
        raise ValueError(f"{kind}{number} has no pre-defined COB-ID; give cob_id")
    return (0x180 if kind == "tpdo" else 0x200) + 0x100 * (number - 1)
