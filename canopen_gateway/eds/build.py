"""The object dictionary of an EDS/DCF, built from its sections with the CiA 306 defaults.

``build_dictionary(text, path, node_id)`` makes a canopen ``ObjectDictionary`` (the types the
rest of the gateway, the SDO client and the simulator use) from the sections ``parse`` read,
and returns every deviation from CiA 306 as a warning with file, line and section. It never
refuses a file: an object it cannot read is left out (and named), a value it cannot read is
left unset (and named). Defaults, as CiA 306 and the common tools (python canopen, Lely,
CANopenNode) read them:

=====================  ===================================================================
missing ``ObjectType``  VAR (0x7), CiA 306 4.6.3.2; DOMAIN (0x2) and DEFTYPE (0x5) are VARs,
                        DEFSTRUCT (0x6) a RECORD, NULL (0x0) is not an object
``SubNumber``           counted from the sub-sections present (a different number: warning)
two spellings           ``[1A00sub1]`` and ``[1A00sub01]``: the first in the file counts, the
                        second is ignored (warning)
``CompactSubObj=n``     sub 00h UNSIGNED8 = n and subs 01h..n of the object's type,
                        names from ``[xxxxName]``, DCF values from ``[xxxxValue]``
``DataType``            missing, or outside CiA 301 table 44 (e.g. 0x0040, manufacturer
                        range): DOMAIN, raw bytes by SDO, not served as a signal (warning)
``AccessType``          any case; missing or unknown: ``ro`` (warning)
``PDOMapping``          any number notation (``0x1``); missing: 0
numbers                 decimal, ``0x`` hex, octal, ``$NODEID+n``; REALs also as hex bit
                        patterns; a value that cannot be read: unset (warning)
empty values            ``VendorNumber=``, ``DefaultValue=``: absent
``[DummyUsage]``        a missing ``DummyNNNN`` is 0
unknown sections        ignored (warning); ``[Comments]``, ``[Tools]``, module sections known
object lists            ``SupportedObjects`` and the entries are compared (warning only)
identity                ``VendorNumber`` / ``ProductNumber`` other than 1018h:01/02 (warning)
=====================  ===================================================================

Imports: canopen (dictionary types), canopen_gateway.eds.parse and the standard library.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from canopen_gateway.eds.parse import (
    ACCESS_TYPES,
    DATA_TYPES,
    MAX_OBJECTS,
    MAX_SUB_OBJECTS,
    OBJECT_TYPES,
    EdsError,
    EdsProblem,
    Section,
    parse_int,
    parse_real,
)

_OBJ = re.compile(r"^([0-9A-Fa-f]{4})$")
_SUB = re.compile(r"^([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})$", re.I)
_AUX = re.compile(r"^([0-9A-Fa-f]{4})(Name|Value|Denotation)$", re.I)

#: Sections that are not objects (CiA 306 / 306-3 for DCF, lower case).
KNOWN_SECTIONS = {
    "fileinfo", "deviceinfo", "dummyusage", "comments", "mandatoryobjects", "optionalobjects",
    "manufacturerobjects", "devicecomissioning", "devicecommissioning", "tools",
    "supportedmodules", "connectedmodules", "dynamicchannels",
}  # fmt: skip
_KNOWN_PATTERNS = [
    re.compile(r"^tool\d+$", re.I),
    re.compile(r"^m\d+(moduleinfo|fixedobjects|subextends|comments)$", re.I),
    re.compile(r"^m\d+subext[0-9a-f]{4}$", re.I),
    re.compile(r"^m\d+fixed[0-9a-f]{4}(sub[0-9a-f]{1,2})?$", re.I),
]
_OBJECT_LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")

VAR, DOMAIN, DEFTYPE, DEFSTRUCT, ARRAY, RECORD, NULL = 0x7, 0x2, 0x5, 0x6, 0x8, 0x9, 0x0
_TEXT = (datatypes.VISIBLE_STRING, datatypes.UNICODE_STRING)
_BYTES = (datatypes.OCTET_STRING, datatypes.DOMAIN)
_INT_BITS = {0x1: 1, 0x2: 8, 0x3: 16, 0x4: 32, 0x5: 8, 0x6: 16, 0x7: 32, 0x10: 24, 0x12: 40,
             0x13: 48, 0x14: 56, 0x15: 64, 0x16: 24, 0x18: 40, 0x19: 48, 0x1A: 56, 0x1B: 64,
             0xC: 48, 0xD: 48}  # fmt: skip
_SIGNED = {0x2, 0x3, 0x4, 0x10, 0x12, 0x13, 0x14, 0x15}


@dataclass
class _Ctx:
    path: str
    node_id: int | None
    dcf: bool
    warnings: list[EdsProblem] = field(default_factory=list)

    def warn(self, sec: Section | None, key: str | None, message: str) -> None:
        line = (sec.line_of(key) if key else sec.line) if sec is not None else 0
        self.warnings.append(EdsProblem(self.path, line, sec.name if sec else "", message))

    def number(
        self, sec: Section, key: str, *, relative_ok: bool = False
    ) -> tuple[int, bool] | None:
        """The number at ``key`` (None when absent or empty); a warning when it is not one."""
        raw = sec.get(key)
        if raw is None or raw == "":
            return None
        try:
            value, rel = parse_int(raw)
        except ValueError as exc:
            head = raw.split("#", 1)[0].strip() if "#" in raw else ""
            got: tuple[int, bool] | None
            try:
                got = parse_int(head) if head else None
            except ValueError:
                got = None
            if got is None:
                self.warn(sec, key, f"{key}={raw}: {exc}; ignored")
                return None
            value, rel = got
            self.warn(sec, key, f"{key}={raw}: text after the number ignored (CiA 306 comments start with ';')")  # fmt: skip
        if rel and not relative_ok:
            self.warn(sec, key, f"{key}={raw}: $NODEID is not allowed here; ignored")
            return None
        return value, rel


def _value(
    ctx: _Ctx, sec: Section, key: str, data_type: int
) -> tuple[object, str | None, bool] | None:
    """(value, raw text kept for $NODEID, relative) of DefaultValue / ParameterValue /
    LowLimit / HighLimit as ``data_type``; None when absent or unreadable (warning)."""
    raw = sec.get(key)
    if raw is None or raw == "":
        return None
    if data_type in _TEXT:
        return raw, raw, False
    if data_type in _BYTES:
        try:
            return bytes.fromhex(raw), raw, False
        except ValueError:
            if data_type == datatypes.DOMAIN:
                return None  # a DOMAIN's default is often a file name or a note: no value
            ctx.warn(sec, key, f"{key}={raw}: not hex bytes; ignored")
            return None
    if data_type in datatypes.FLOAT_TYPES:
        try:
            return parse_real(raw, 32 if data_type == datatypes.REAL32 else 64), raw, False
        except ValueError as exc:
            ctx.warn(sec, key, f"{key}={raw}: {exc}; ignored")
            return None
    got = ctx.number(sec, key, relative_ok=key in ("DefaultValue", "ParameterValue"))
    if got is None:
        return None
    value, rel = got
    bits = _INT_BITS.get(data_type)
    if bits is not None and not rel:
        lo = -(1 << (bits - 1)) if data_type in _SIGNED else 0
        hi = (1 << (bits - 1)) - 1 if data_type in _SIGNED else (1 << bits) - 1
        if data_type in _SIGNED and hi < value < (1 << bits) and raw.strip()[:2].lower() == "0x":
            value -= 1 << bits  # a negative value written as its two's complement in hex
        elif not lo <= value <= hi:
            ctx.warn(sec, key, f"{key}={raw}: outside {DATA_TYPES.get(data_type)} ({lo}..{hi}); ignored")  # fmt: skip
            return None
    text = f"$NODEID+0x{value:X}" if rel else raw
    return value, text, rel


def _variable(ctx: _Ctx, sec: Section, index: int, sub: int, name: str | None = None) -> ODVariable:
    pn = sec.get("ParameterName")
    if name is None:
        if not pn:
            ctx.warn(sec, None, "ParameterName is missing or empty")
        name = pn or ""
    var = ODVariable(name, index, sub)
    var.storage_location = sec.get("StorageLocation")
    dt = ctx.number(sec, "DataType")
    if dt is None:
        if sec.get("DataType") is None:
            ctx.warn(sec, None, "DataType is missing: read as DOMAIN (raw bytes)")
        data_type = datatypes.DOMAIN
    else:
        data_type = dt[0]
        if data_type not in DATA_TYPES:
            ctx.warn(sec, "DataType", f"DataType=0x{data_type:04X} is not a CiA 301 basic data type: read as DOMAIN (raw bytes)")  # fmt: skip
            data_type = datatypes.DOMAIN
    var.data_type = data_type
    acc = sec.get("AccessType")
    if acc is None or acc.strip().lower() not in ACCESS_TYPES:
        if acc is None:
            ctx.warn(sec, None, "AccessType is missing: read as ro")
        else:
            ctx.warn(sec, "AccessType", f"AccessType={acc}: not one of {', '.join(sorted(ACCESS_TYPES))}; read as ro")  # fmt: skip
        var.access_type = "ro"
    else:
        var.access_type = acc.strip().lower()
    pm = ctx.number(sec, "PDOMapping")
    if pm is not None and pm[0] not in (0, 1):
        ctx.warn(sec, "PDOMapping", f"PDOMapping={sec.get('PDOMapping')}: must be 0 or 1; read as {int(bool(pm[0]))}")  # fmt: skip
    var.pdo_mappable = bool(pm[0]) if pm is not None else False
    for key, attr in (("LowLimit", "min"), ("HighLimit", "max")):
        got = _value(ctx, sec, key, data_type) if data_type not in _TEXT + _BYTES else None
        if got is not None and not got[2]:
            setattr(var, attr, got[0])
    got = _value(ctx, sec, "DefaultValue", data_type)
    if got is not None:
        value, text, rel = got
        var.default_raw = text
        var.relative = rel
        var.default = (value + ctx.node_id if ctx.node_id is not None else None) if rel else value  # type: ignore[operator]
    if ctx.dcf or sec.get("ParameterValue") is not None:
        got = _value(ctx, sec, "ParameterValue", data_type)
        if got is not None:
            value, text, rel = got
            var.value_raw = text
            var.value = (value + ctx.node_id if ctx.node_id is not None else None) if rel else value  # type: ignore[operator]
    for key, attr in (("Description", "description"), ("Unit", "unit")):
        if sec.get(key):
            setattr(var, attr, sec.get(key))
    return var


def _object_type(ctx: _Ctx, sec: Section, has_subs: bool) -> int:
    got = ctx.number(sec, "ObjectType")
    if got is None:
        if sec.get("ObjectType") not in (None, ""):
            guess = RECORD if has_subs else VAR
            ctx.warn(sec, "ObjectType", f"read as {OBJECT_TYPES[guess]}")
            return guess
        return RECORD if has_subs and sec.get("SubNumber") else VAR
    ot = got[0]
    if ot not in OBJECT_TYPES:
        guess = RECORD if has_subs else VAR
        ctx.warn(sec, "ObjectType", f"ObjectType={sec.get('ObjectType')} is not a CiA 306 object type: read as {OBJECT_TYPES[guess]}")  # fmt: skip
        return guess
    return ot


def _compact(
    ctx: _Ctx, sec: Section, index: int, name: str, ot: int, sections: dict[str, Section]
) -> ODArray | ODRecord:
    """CiA 306 4.5.2.3: ``CompactSubObj=n``: sub 00h = n, subs 01h..n like the object."""
    n = ctx.number(sec, "CompactSubObj")
    count = max(0, min(n[0] if n else 0, 0xFE))
    obj = ODArray(name, index) if ot == ARRAY else ODRecord(name, index)
    obj.storage_location = sec.get("StorageLocation")
    sub0 = ODVariable("Number of entries", index, 0)
    sub0.data_type = datatypes.UNSIGNED8
    sub0.access_type = "ro"
    sub0.default = count
    sub0.default_raw = str(count)
    obj.add_member(sub0)
    names = sections.get(f"{index:04x}name")
    values = sections.get(f"{index:04x}value")
    for s in range(1, count + 1):
        sub_name = (names.get(str(s)) if names else None) or f"{name}{s}"
        var = _variable(ctx, sec, index, s, name=sub_name)
        if values is not None and values.get(str(s)) not in (None, ""):
            tmp = Section(values.name, values.line, {"parametervalue": values.keys[str(s)]})
            got = _value(ctx, tmp, "ParameterValue", var.data_type or datatypes.DOMAIN)
            if got is not None:
                var.value_raw, var.value = got[1], got[0]
        obj.add_member(var)
    return obj


def _device_info(ctx: _Ctx, od: canopen.ObjectDictionary, sections: dict[str, Section]) -> None:
    info = sections.get("deviceinfo")
    if info is None:
        ctx.warnings.append(
            EdsProblem(ctx.path, 1, "DeviceInfo", "section [DeviceInfo] is missing")
        )
        return
    di = od.device_information
    for rate in (10, 20, 50, 125, 250, 500, 800, 1000):
        got = ctx.number(info, f"BaudRate_{rate}")
        if got is not None and got[0]:
            di.allowed_baudrates.add(rate * 1000)
    for key, attr in (("VendorName", "vendor_name"), ("ProductName", "product_name"), ("OrderCode", "order_code")):  # fmt: skip
        if info.get(key):
            setattr(di, attr, info.get(key))
    for key, attr, conv in (
        ("VendorNumber", "vendor_number", int), ("ProductNumber", "product_number", int),
        ("RevisionNumber", "revision_number", int), ("NrOfRXPDO", "nr_of_RXPDO", int),
        ("NrOfTXPDO", "nr_of_TXPDO", int), ("SimpleBootUpMaster", "simple_boot_up_master", bool),
        ("SimpleBootUpSlave", "simple_boot_up_slave", bool), ("Granularity", "granularity", int),
        ("DynamicChannelsSupported", "dynamic_channels_supported", bool),
        ("GroupMessaging", "group_messaging", bool), ("LSS_Supported", "LSS_supported", bool),
    ):  # fmt: skip
        got = ctx.number(info, key)
        if got is not None:
            setattr(di, attr, conv(got[0]))


def _object_lists(ctx: _Ctx, sections: dict[str, Section], objects: dict[int, Section]) -> None:
    listed: set[int] = set()
    for list_name in _OBJECT_LISTS:
        sec = sections.get(list_name.lower())
        if sec is None:
            continue
        entries = {k: v for k, v in sec.keys.items() if k != "supportedobjects"}
        count = ctx.number(sec, "SupportedObjects")
        if count is not None and count[0] != len(entries):
            ctx.warn(sec, "SupportedObjects", f"SupportedObjects={sec.get('SupportedObjects')} but {len(entries)} entries are listed")  # fmt: skip
        for key, (value, line) in entries.items():
            tmp = Section(sec.name, sec.line, {key: (value, line)})
            got = ctx.number(tmp, key)
            if got is None:
                continue
            listed.add(got[0])
            if got[0] not in objects:
                ctx.warnings.append(EdsProblem(ctx.path, line, sec.name, f"object 0x{got[0]:04X} is listed but has no section [{got[0]:04X}]"))  # fmt: skip
    if listed:
        for index, sec in sorted(objects.items()):
            if index >= 0x1000 and index not in listed:
                ctx.warn(sec, None, "object is not listed in [MandatoryObjects], [OptionalObjects] or [ManufacturerObjects]")  # fmt: skip


def _identity_agrees(ctx: _Ctx, od: canopen.ObjectDictionary, sections: dict[str, Section]) -> None:
    """[DeviceInfo] VendorNumber / ProductNumber against 1018h:01 / 02 (a DCF's ParameterValue,
    else the DefaultValue): where they differ the identity check at boot does not compare that
    number (profiles.expected_identity)."""
    info = sections.get("deviceinfo")
    ident = od.get(0x1018)
    if info is None or ident is None or isinstance(ident, ODVariable):
        return
    for key, sub, given in (("VendorNumber", 1, od.device_information.vendor_number),
                            ("ProductNumber", 2, od.device_information.product_number)):  # fmt: skip
        var = ident.subindices.get(sub)
        held = getattr(var, "value", None) if getattr(var, "value", None) is not None else getattr(var, "default", None)  # fmt: skip
        what = "ParameterValue" if getattr(var, "value", None) is not None else "DefaultValue"
        if isinstance(given, int) and isinstance(held, int) and given != held:
            ctx.warn(info, key, f"{key}=0x{given:X} but 1018h:{sub:02X} {what}=0x{held:X}: the identity check at boot does not compare it")  # fmt: skip


def _commissioning(
    ctx: _Ctx, od: canopen.ObjectDictionary, sections: dict[str, Section], node_id: int | None
) -> None:
    """[DeviceComissioning]: the bit rate, and the node id unless the caller gives one."""
    com = sections.get("devicecomissioning") or sections.get("devicecommissioning")
    if com is None:
        return
    rate = ctx.number(com, "Baudrate")
    if rate is not None and rate[0]:
        od.bitrate = rate[0] * 1000
    if node_id is None:
        nid = ctx.number(com, "NodeID")
        if nid is not None and 1 <= nid[0] <= 127:
            ctx.node_id = nid[0]
    od.node_id = ctx.node_id


def _dummy_usage(ctx: _Ctx, od: canopen.ObjectDictionary, sections: dict[str, Section]) -> None:
    """[DummyUsage]: a const variable at index 0001h..0007h per dummy type the device maps."""
    dummy = sections.get("dummyusage")
    if dummy is None:
        return
    for i in range(1, 8):
        got = ctx.number(dummy, f"Dummy{i:04X}")
        if got is not None and got[0] not in (0, 1):
            ctx.warn(dummy, f"Dummy{i:04X}", f"Dummy{i:04X}={dummy.get(f'Dummy{i:04X}')}: must be 0 or 1")  # fmt: skip
        if got is not None and got[0]:
            var = ODVariable(f"Dummy{i:04d}", i, 0)
            var.data_type = i
            var.access_type = "const"
            od.add_object(var)


def _bounded(ctx: _Ctx, objects: dict[int, Section], subs: dict[int, list[tuple[int, Section]]]) -> None:
    """EdsError before anything is built when the file makes more objects or sub-objects than
    a device has (``parse.MAX_OBJECTS``, ``MAX_SUB_OBJECTS``; CompactSubObj counts as written)."""
    if len(objects) > MAX_OBJECTS:
        raise EdsError([f"{ctx.path}: {len(objects)} objects, more than {MAX_OBJECTS}: not a device "
                        "description the gateway loads"])  # fmt: skip
    total = 0
    for index, sec in objects.items():
        compact = sec.get("CompactSubObj")
        if compact and not subs.get(index):
            try:
                n = parse_int(compact)[0]
            except ValueError:
                n = 0  # the build warns about it
            total += 1 + max(0, min(n, 0xFE))
        else:
            total += 1 + len(subs.get(index, ()))
    if total > MAX_SUB_OBJECTS:
        raise EdsError([f"{ctx.path}: {total} objects and sub-objects, more than {MAX_SUB_OBJECTS}: "
                        "not a device description the gateway loads"])  # fmt: skip


def build_dictionary(
    sections: dict[str, Section], path: str, node_id: int | None = None
) -> tuple[canopen.ObjectDictionary, list[EdsProblem]]:
    """The dictionary of the file and its warnings (see the module docstring)."""
    ctx = _Ctx(path, node_id, path.lower().endswith(".dcf"))
    od = canopen.ObjectDictionary()
    objects: dict[int, Section] = {}
    subs: dict[int, list[tuple[int, Section]]] = {}
    for sec in sections.values():
        name = sec.name
        if m := _OBJ.match(name):
            objects[int(m.group(1), 16)] = sec
        elif m := _SUB.match(name):
            subs.setdefault(int(m.group(1), 16), []).append((int(m.group(2), 16), sec))
        elif _AUX.match(name):
            continue
        elif name.lower() in KNOWN_SECTIONS or any(p.match(name) for p in _KNOWN_PATTERNS):
            continue
        else:
            ctx.warn(sec, None, "unknown section: neither an object ([6401], [6401sub2]) nor a CiA 306 section; ignored")  # fmt: skip
    _bounded(ctx, objects, subs)
    _device_info(ctx, od, sections)
    _commissioning(ctx, od, sections, node_id)
    _dummy_usage(ctx, od, sections)
    for index, sec in sorted(objects.items()):
        own = sorted(subs.get(index, []), key=lambda x: (x[0], x[1].line))
        ot = _object_type(ctx, sec, bool(own))
        if ot == NULL:
            continue
        name = sec.get("ParameterName") or ""
        if not name:
            ctx.warn(sec, None, "ParameterName is missing or empty")
        if ot in (VAR, DOMAIN, DEFTYPE):
            if own:
                ctx.warn(own[0][1], None, f"sub-section of [{sec.name}], which is not an ARRAY or RECORD; ignored")  # fmt: skip
            od.add_object(_variable(ctx, sec, index, 0, name=name))
            continue
        if sec.get("CompactSubObj") not in (None, "") and not own:
            od.add_object(_compact(ctx, sec, index, name, ot, sections))
            continue
        obj: ODArray | ODRecord = ODArray(name, index) if ot == ARRAY else ODRecord(name, index)
        obj.storage_location = sec.get("StorageLocation")
        sn = ctx.number(sec, "SubNumber")
        n_subs = len({sub for sub, _ in own})
        if sn is not None and sn[0] != n_subs:
            found = ", ".join(f"[{s.name}]" for _, s in own) or "none"
            ctx.warn(sec, "SubNumber", f"SubNumber={sec.get('SubNumber')} but {n_subs} sub-sections follow ({found}); the sub-sections count")  # fmt: skip
        for sub, ssec in own:
            if sub in obj.subindices:  # [1A00sub1] and [1A00sub01]: the first in the file counts
                first = next(f for n, f in own if n == sub)
                ctx.warn(ssec, None, f"sub-index {sub:02X}h again (first as [{first.name}] at line {first.line}): ignored")  # fmt: skip
                continue
            sot = ctx.number(ssec, "ObjectType")
            if sot is not None and sot[0] not in (VAR, DOMAIN):
                ctx.warn(ssec, "ObjectType", f"ObjectType={ssec.get('ObjectType')}: a sub-object is a VAR (0x7); read as VAR")  # fmt: skip
            obj.add_member(_variable(ctx, ssec, index, sub))
        od.add_object(obj)
    for index, lst in subs.items():
        if index not in objects:
            for _, s in lst:
                ctx.warn(s, None, f"sub-section without its object [{index:04X}]; ignored")
    _object_lists(ctx, sections, objects)
    _identity_agrees(ctx, od, sections)
    ctx.warnings.sort(key=lambda p: p.line)
    return od, ctx.warnings
