"""The boot configuration of a node: the ordered SDO writes derived from its profile (or EDS)
and its node settings (supervision, TPDO transmission, PDO remapping, the profile's and the
user's writes). ``build_boot_steps`` is the one place the CiA 301 PDO sequence is written; the
lifecycle (``bus/node/lifecycle.py``) plays the steps, the codecs follow the same layout.

Imports: canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref, canopen_gateway.device.values, canopen_gateway.eds.pdos, canopen_gateway.profiles (layout,
node_setup, schema; LoadedProfile for types only) and the standard library. No I/O, no clock. The
node is read as a ``NodeSetup`` (``canopen_gateway.config.NodeConfig.setup`` builds it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from canopen_gateway.canopen.cia301 import (
    COB_ID_INVALID,
    OBJ_GUARD_TIME,
    OBJ_HEARTBEAT_PRODUCER,
    OBJ_LIFE_TIME_FACTOR,
    TYPE_NAMES,
)
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.device.values import encode_value
from canopen_gateway.eds.pdos import default_value
from canopen_gateway.profiles.layout import pdo_cob_id, pdo_objects
from canopen_gateway.profiles.node_setup import NodeSetup, PdoSetup, SdoSetup
from canopen_gateway.profiles.schema import BootWrite, Pdo, default_cob_id

if TYPE_CHECKING:
    from canopen_gateway.profiles import LoadedProfile


@dataclass(frozen=True)
class ConfigStep:
    """One SDO download of the boot configuration."""

    object: ObjRef
    value: int | float | str
    type: str  # profile type name: uint8, uint16, uint32, int32, string, ...
    description: str = ""
    optional: bool = False  # a refusal (SDO abort) is reported and the step skipped
    #: the node config key it comes from, e.g. "heartbeat_ms", "tpdo.1.mapping" (for messages)
    source: str = field(default="", compare=False)

    @property
    def data(self) -> bytes:
        """The bytes of the download (little endian, as DS-301 sends them)."""
        return encode_value(self.value, self.type)

    @property
    def size(self) -> int:
        return len(self.data)

    def __str__(self) -> str:
        v = self.value
        shown = (
            f"{v} (0x{v:X})"
            if isinstance(v, int) and v > 9
            else repr(v)
            if isinstance(v, str)
            else v
        )
        text = f"{self.object} = {shown} {self.type}"
        return f"{text}: {self.description}" if self.description else text


@dataclass
class _Builder:
    lp: LoadedProfile
    steps: list[ConfigStep] = field(default_factory=list)
    derived: set[int] = field(default_factory=set)  # indexes of plain derived writes

    def od_type(self, obj: ObjRef, where: str) -> tuple[str, Any]:
        var = self.lp.od_var(obj)
        if var is None:
            raise ValueError(f"{where}: {obj} is not in {self.lp.eds_path.name}")
        type_name = TYPE_NAMES.get(var.data_type)
        if type_name is None:
            raise ValueError(f"{where}: {obj} has a data type the gateway cannot write")
        return type_name, var

    def add(
        self,
        obj: ObjRef,
        value: int,
        description: str,
        where: str,
        *,
        derived: bool = False,
        source: str = "",
    ) -> None:
        """Add a write computed by the builder, checked against the EDS."""
        type_name, var = self.od_type(obj, where)
        if not var.writable:
            default = var.default
            if default is not None and int(default) == value:
                return  # read-only and already what we want
            raise ValueError(
                f"{where}: {obj} is read-only ({var.access_type}) in {self.lp.eds_path.name}, "
                f"cannot set it to {value}"
            )
        if derived:
            self.derived.add(len(self.steps))
        self.steps.append(ConfigStep(obj, value, type_name, description, source=source))

    def add_explicit(self, w: BootWrite | SdoSetup, where: str, source: str = "") -> None:
        """A write from the profile's boot.sdo or the node's sdo list."""
        obj = ObjRef.parse(w.object)
        od_type, var = self.od_type(obj, where)
        if not var.writable:
            raise ValueError(
                f"{where}: {obj} is read-only ({var.access_type}) in {self.lp.eds_path.name}"
            )
        type_name = w.type or od_type
        value = _coerce(w.value, type_name, f"{where} ({obj})")
        self.steps.append(ConfigStep(obj, value, type_name, w.note or where, source=source))

    def result(self) -> list[ConfigStep]:
        """Steps, dropping derived plain writes that an explicit write sets again later."""
        out = []
        for i, s in enumerate(self.steps):
            if i in self.derived and any(t.object == s.object for t in self.steps[i + 1 :]):
                continue
            out.append(s)
        return out


def _coerce(value: Any, type_name: str, where: str) -> int | float | str:
    """A config/profile value as the number or text to download.

    A text for a numeric type is a number (``"0x10"``) or a 4-character signature such as
    ``"save"`` (1010h) / ``"load"`` (1011h), sent as its ASCII bytes: ``"save"`` is
    0x65766173 little endian (BEI manual, 1010h).
    """
    if type_name in ("string", "bytes"):
        return str(value)
    if isinstance(value, str):
        try:
            return int(value.replace("_", ""), 0)
        except ValueError:
            raw = value.encode("ascii", errors="strict")
            size = len(encode_value(0, type_name))
            if len(raw) != size:
                raise ValueError(
                    f"{where}: {value!r} is neither a number nor a {size}-character signature"
                ) from None
            return int.from_bytes(raw, "little")
    if type_name in ("float32", "float64"):
        return float(value)
    if isinstance(value, float):
        if not value.is_integer():
            raise ValueError(f"{where}: {value} is not an integer ({type_name})")
        return int(value)
    return int(value)


def _mapping_entry(obj: ObjRef, bits: int) -> int:
    """DS-301 mapping entry: index << 16 | sub << 8 | length in bits (MSK5000 manual 4.3.1.2)."""
    return (obj.index << 16) | (obj.sub << 8) | bits


def _pdo_sequence(
    b: _Builder,
    kind: Literal["tpdo", "rpdo"],
    pdo: Pdo,
    comm: int,
    mapping: int,
    node_id: int,
    where: str,
    *,
    params: Sequence[tuple[int, int, str, str]] = (),
    remap: bool = True,
) -> None:
    """The CiA 301 sequence that (re)configures one PDO in PRE-OPERATIONAL (CiA 301 7.5.2.35 ..
    7.5.2.38; MSK5000 manual 4.3.1.2 steps 2-6): COB-ID with bit 31 set (PDO not valid), the
    communication ``params`` (sub, value, description, config key), mapping sub 00h = 0,
    the entries 01h.., sub 00h = n, COB-ID with bit 31 clear. The one builder of this sequence:
    the remappable_tpdo feature and the nodes' ``tpdo:``/``rpdo:`` settings both use it.
    """
    name = f"{kind.upper()}{pdo.number}"
    cob_id = pdo_cob_id(kind, pdo, node_id)
    b.add(ObjRef(comm, 0x01), cob_id | COB_ID_INVALID, f"{name} off (COB-ID bit 31 = 1)", where, source=f"{where}.cob_id")  # fmt: skip
    for sub, value, text, key in params:
        b.add(ObjRef(comm, sub), value, f"{name} {text}", where, source=key)
    if remap:
        b.add(ObjRef(mapping, 0x00), 0, f"{name} mapping off", where, source=f"{where}.mapping")
        for i, e in enumerate(pdo.mapping, start=1):
            b.add(
                ObjRef(mapping, i),
                _mapping_entry(e.object, e.bits),
                f"{name} entry {i}: {e.object}, {e.bits} bit",
                where,
                source=f"{where}.mapping[{i - 1}]",
            )
        b.add(
            ObjRef(mapping, 0x00),
            len(pdo.mapping),
            f"{name} mapping on, {len(pdo.mapping)} entries",
            where,
            source=f"{where}.mapping",
        )
    b.add(ObjRef(comm, 0x01), cob_id, f"{name} on (COB-ID bit 31 = 0)", where, source=f"{where}.cob_id")  # fmt: skip


def build_boot_steps(lp: LoadedProfile, node: NodeSetup) -> list[ConfigStep]:
    """The ordered SDO writes that configure a node at boot.

    1. supervision: producer heartbeat 1017h; or node guarding 100Ch/100Dh with 1017h = 0
       (DS-301: a producer heartbeat time other than 0 takes precedence over guarding);
    2. the external heartbeat objects when the node config asks for it (feature
       ``external_heartbeat``, AP05 manual 5.5.4, 5F09h: source, then interval);
    3. the PDO layout selector when a variant is chosen (feature ``pdo_type_selector``);
    4. per PDO the node's ``tpdo:``/``rpdo:`` settings name: the CiA 301 sequence
       (``_pdo_sequence``): COB-ID with bit 31 set, the parameters given (transmission type,
       inhibit time, event timer, SYNC start), mapping sub 00h = 0, the entries, sub 00h = n,
       COB-ID with bit 31 clear; or only the COB-ID with bit 31 set for ``enabled: false``.
       Per TPDO of the profile's own layout: transmission type 180xh:02 and event timer
       180xh:05; then, when the profile has ``remappable_tpdo`` (or a non-default inhibit
       time), the same sequence (MSK5000 manual 4.3.1.2). PDOs taken from the EDS as they are
       need no writes;
    5. the profile's ``boot.sdo`` writes;
    6. the node config's ``sdo`` writes.

    Derived writes of 1.-4. that 5. or 6. write again are left out (the explicit value wins).
    Objects are checked against the EDS: a missing object or a read-only one the profile wants
    changed raises ValueError naming it. Types come from the EDS (1A00h:00 is UNSIGNED8, so it
    is written with one byte). One function per step below, in this order.
    """
    b = _Builder(lp)
    _step1_supervision(b, node)
    _step2_external_heartbeat(b, node)
    _step3_pdo_variant(b, node)
    _step4_pdos(b, node)
    _step5_profile_writes(b)
    _step6_node_writes(b, node)
    return b.result()


def _step1_supervision(b: _Builder, node: NodeSetup) -> None:
    """1. supervision: producer heartbeat 1017h, or node guarding 100Ch/100Dh with 1017h = 0."""
    boot = b.lp.profile.boot
    supervision = node.supervision or boot.supervision
    heartbeat_ms, guard_time_ms = node.heartbeat_ms, node.guard_time_ms
    life_time_factor = node.life_time_factor
    hb_ms = boot.heartbeat_ms if heartbeat_ms is None else heartbeat_ms
    gt_ms = boot.guard_time_ms if guard_time_ms is None else guard_time_ms
    ltf = boot.life_time_factor if life_time_factor is None else life_time_factor
    if supervision == "heartbeat":
        b.add(
            OBJ_HEARTBEAT_PRODUCER, hb_ms, "producer heartbeat time (ms)", "heartbeat", derived=True,
            source="heartbeat_ms" if heartbeat_ms is not None else "",
        )  # fmt: skip
    elif supervision == "guarding":
        if b.lp.od_var(OBJ_HEARTBEAT_PRODUCER) is not None:
            b.add(
                OBJ_HEARTBEAT_PRODUCER,
                0,
                "heartbeat off: node guarding is used",
                "guarding",
                derived=True,
            )
        b.add(OBJ_GUARD_TIME, gt_ms, "guard time (ms)", "guarding", derived=True,
              source="guard_time_ms" if guard_time_ms is not None else "")  # fmt: skip
        b.add(OBJ_LIFE_TIME_FACTOR, ltf, "life time factor", "guarding", derived=True,
              source="life_time_factor" if life_time_factor is not None else "")  # fmt: skip


def _step2_external_heartbeat(b: _Builder, node: NodeSetup) -> None:
    """2. the external heartbeat source, then interval (AP05 manual 5.5.4 / 5.7.2.31)."""
    p = b.lp.profile
    ext = node.external_heartbeat
    feat = p.features.get("external_heartbeat")
    if ext is None or not ext.interval_ms:
        return
    if feat is None:
        raise ValueError(
            f"external_heartbeat: profile {p.family} has no feature external_heartbeat"
        )
    codes = {str(v): int(k) for k, v in (feat.get("sources") or {0: "rpdo", 1: "sync"}).items()}
    if ext.source not in codes:
        raise ValueError(f"external_heartbeat.source: {ext.source!r} not one of {sorted(codes)}")
    b.add(
        ObjRef.parse(feat["source"]),
        codes[ext.source],
        f"external heartbeat source = {ext.source}",
        "external_heartbeat",
        derived=True,
        source="external_heartbeat.source",
    )
    b.add(
        ObjRef.parse(feat["interval"]),
        int(ext.interval_ms),
        "external heartbeat interval (ms)",
        "external_heartbeat",
        derived=True,
        source="external_heartbeat.interval_ms",
    )


def _step3_pdo_variant(b: _Builder, node: NodeSetup) -> None:
    """3. the PDO layout selector (BEI 2005h) when a variant is chosen."""
    p = b.lp.profile
    variant = node.pdo_variant
    if p.pdo_variants is not None and variant is not None:
        b.add(
            p.pdo_variants.selector,
            int(variant),
            f"PDO layout variant {variant}",
            "pdo_variant",
            derived=True,
            source="pdo_variant",
        )


def _step4_pdos(b: _Builder, node: NodeSetup) -> None:
    """4. PDOs. The node's tpdo:/rpdo: settings: the CiA 301 sequence from the node's layout
    (canopen_gateway.profiles.layout resolved it; the codecs are compiled from the same layout).
    The profile's own TPDOs: transmission type and event timer, and the same sequence when
    the profile has remappable_tpdo (or a non-default inhibit time)."""
    p = b.lp.profile
    tpdos, rpdos = p.layout(node.pdo_variant)
    settings = {"tpdo": node.tpdo, "rpdo": node.rpdo}
    for kind, pdos in (("tpdo", tpdos), ("rpdo", rpdos)):
        k: Literal["tpdo", "rpdo"] = kind  # type: ignore[assignment]
        by_number = {x.number: x for x in pdos}
        for number in sorted(set(by_number) | set(settings[k])):
            pdo = by_number.get(number)
            setting = settings[k].get(number)
            if setting is not None:
                _node_pdo(b, k, number, pdo, setting, node.node_id)
            elif k == "tpdo" and pdo is not None and pdo.origin == "profile":
                _profile_tpdo(b, pdo, node.node_id)
            # else: an EDS PDO as the device holds it: nothing to write


def _node_pdo(
    b: _Builder,
    k: Literal["tpdo", "rpdo"],
    number: int,
    pdo: Pdo | None,
    setting: PdoSetup,
    node_id: int,
) -> None:
    """4. one PDO the node's ``tpdo:``/``rpdo:`` settings name: disabled (``enabled: false``,
    only the COB-ID with bit 31 set), else the CiA 301 sequence with the parameters given."""
    comm, mapping = pdo_objects(b.lp.profile, k, number)
    where = f"{k}.{number}"
    if pdo is None:  # enabled: false
        held = default_value(b.lp.od_var(ObjRef(comm, 0x01)), node_id)
        if held is None:
            held = default_cob_id(k, number) + node_id if number <= 4 else 0
        b.add(
            ObjRef(comm, 0x01),
            int(held) | COB_ID_INVALID,
            f"{k.upper()}{number} disabled (COB-ID bit 31 = 1)",
            where,
            source=f"{where}.enabled",
        )
        return
    params: list[tuple[int, int, str, str]] = []
    if setting.transmission is not None:
        params.append((0x02, pdo.transmission_type, "transmission type", f"{where}.transmission"))  # fmt: skip
    if k == "tpdo" and setting.inhibit_ms is not None:
        params.append((0x03, pdo.inhibit_time_100us or 0, "inhibit time (100 us)", f"{where}.inhibit_ms"))  # fmt: skip
    if setting.event_timer_ms is not None:
        params.append((0x05, pdo.event_timer_ms or 0, "event timer (ms)", f"{where}.event_timer_ms"))  # fmt: skip
    if k == "tpdo" and setting.sync_start is not None:
        params.append((0x06, pdo.sync_start or 0, "SYNC start value", f"{where}.sync_start"))  # fmt: skip
    _pdo_sequence(b, k, pdo, comm, mapping, node_id, where, params=params,
                  remap=setting.mapping is not None or pdo.origin == "config")  # fmt: skip


def _profile_tpdo(b: _Builder, pdo: Pdo, node_id: int) -> None:
    """4. one TPDO of the profile's own layout: transmission type 180xh:02 and event timer
    180xh:05; the CiA 301 sequence when the profile has ``remappable_tpdo`` or the inhibit
    time differs from the EDS default."""
    lp = b.lp
    comm, mapping = pdo_objects(lp.profile, "tpdo", pdo.number)
    where = f"tpdos[{pdo.number}]"
    b.add(
        ObjRef(comm, 0x02),
        pdo.transmission_type,
        f"TPDO{pdo.number} transmission type",
        where,
        derived=True,
    )
    if pdo.event_timer_ms is not None:
        b.add(
            ObjRef(comm, 0x05),
            pdo.event_timer_ms,
            f"TPDO{pdo.number} event timer (ms)",
            where,
            derived=True,
        )
    inhibit = pdo.inhibit_time_100us
    inhibit_var = lp.od_var(ObjRef(comm, 0x03)) if inhibit is not None else None
    write_inhibit = (
        inhibit is not None
        and inhibit_var is not None
        and not (inhibit_var.default is not None and int(inhibit_var.default) == inhibit)
    )
    if inhibit is not None and inhibit_var is None and inhibit != 0:
        raise ValueError(f"{where}: {ObjRef(comm, 0x03)} is not in {lp.eds_path.name}")
    remap = lp.profile.features.get("remappable_tpdo")
    if not (remap is not None or write_inhibit):
        return
    inhibit_param = (
        [(0x03, int(inhibit), "inhibit time (100 us)", where)] if write_inhibit else []  # type: ignore[arg-type]
    )
    _pdo_sequence(b, "tpdo", pdo, comm, mapping, node_id, where, params=inhibit_param,
                  remap=remap is not None)  # fmt: skip


def _step5_profile_writes(b: _Builder) -> None:
    """5. the profile's ``boot.sdo`` writes."""
    p = b.lp.profile
    for i, w in enumerate(p.boot.sdo):
        b.add_explicit(w, f"profile {p.family} boot.sdo[{i}]")


def _step6_node_writes(b: _Builder, node: NodeSetup) -> None:
    """6. the node config's ``sdo`` writes."""
    for i, w in enumerate(node.sdo):
        b.add_explicit(w, f"node sdo[{i}]", source=f"sdo[{i}]")
