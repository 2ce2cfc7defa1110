"""The object dictionary values of one simulated node, and its persistent store.

Knows an EDS's entries (from canopen's parsed ``ObjectDictionary``): data type, access, limits,
defaults with ``$NODEID`` resolved (a DCF's ParameterValue first, CompactSubObj ``[xxxxValue]``
included: what the gateway reads from the same file, ``canopen_gateway.eds.pdos.default_value``). Values live in a dict keyed by (index, sub) as Python values
(int, float, str, bytes); this module encodes/decodes them to the little-endian bytes of SDO and
PDO transfers and raises :class:`SdoAbortError` with the DS-301 abort code when an access is
refused. It knows nothing of NMT, PDO rules or device features (node.py does).

Imports: canopen (object dictionary types only), canopen_gateway.eds.pdos (default_value),
canopen_gateway.canopen.objref.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes as dt

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.eds.pdos import default_value

# DS-301 7.2.4.3.17 SDO abort codes used by the server (also listed in SGH10 manual 4.4.1.3)
ABORT_TOGGLE = 0x05030000  # toggle bit not alternated
ABORT_TIMEOUT = 0x05040000  # SDO protocol timed out
ABORT_COMMAND = 0x05040001  # client/server command specifier not valid or unknown
ABORT_ACCESS = 0x06010000  # unsupported access to an object
ABORT_WRITE_ONLY = 0x06010001  # attempt to read a write only object
ABORT_READ_ONLY = 0x06010002  # attempt to write a read only object
ABORT_NO_OBJECT = 0x06020000  # object does not exist in the object dictionary
ABORT_NOT_MAPPABLE = 0x06040041  # object cannot be mapped to the PDO
ABORT_PDO_LENGTH = 0x06040042  # number and length of objects to be mapped exceeds PDO length
ABORT_LENGTH = 0x06070010  # data type does not match, length of service parameter does not
ABORT_LENGTH_HIGH = 0x06070012  # length of service parameter too high
ABORT_NO_SUB = 0x06090011  # sub-index does not exist
ABORT_RANGE = 0x06090030  # value range of parameter exceeded
ABORT_GENERAL = 0x08000000  # general error
ABORT_STORE = 0x08000020  # data cannot be transferred or stored to the application
ABORT_STATE = 0x08000022  # ... because of the present device state
ABORT_NO_DATA = 0x08000024  # no data available


class SdoAbortError(Exception):
    """An access refused with a DS-301 SDO abort code."""

    def __init__(self, code: int, detail: str = "") -> None:
        super().__init__(f"SDO abort 0x{code:08X}{': ' + detail if detail else ''}")
        self.code = code


_STRING_TYPES = (dt.VISIBLE_STRING, dt.OCTET_STRING, dt.UNICODE_STRING, dt.DOMAIN)


def resolve_default(var: od.ODVariable, node_id: int) -> Any:
    """The value the device holds after power-on without a store: a DCF's ParameterValue, else
    the EDS default, ``$NODEID`` replaced by ``node_id`` (0 / "" if none)."""
    value = default_value(var, node_id)
    if value is not None:
        return value
    if var.data_type in (dt.VISIBLE_STRING, dt.UNICODE_STRING):
        return ""
    if var.data_type in (dt.OCTET_STRING, dt.DOMAIN):
        return b""
    if var.data_type in dt.FLOAT_TYPES:
        return 0.0
    return 0


def type_size(var: od.ODVariable) -> int | None:
    """Bytes of a fixed-size type; None for strings and domains."""
    st = od.ODVariable.STRUCT_TYPES.get(var.data_type or 0)  # None: no type, no size
    if st is not None:
        return st.size
    if var.data_type == dt.BOOLEAN:
        return 1
    return None


def bit_size(var: od.ODVariable) -> int:
    size = type_size(var)
    return 8 * size if size is not None else 0


def is_signed(var: od.ODVariable) -> bool:
    return var.data_type in dt.SIGNED_TYPES


def encode(var: od.ODVariable, value: Any) -> bytes:
    """Little-endian bytes of ``value`` as the type of ``var``."""
    if var.data_type == dt.VISIBLE_STRING:
        # UTF-8: device names in EDS files are often not ASCII ("Größe")
        return value.encode("utf-8") if isinstance(value, str) else bytes(value)
    if var.data_type == dt.UNICODE_STRING:
        return value.encode("utf_16_le") if isinstance(value, str) else bytes(value)
    if var.data_type in (dt.OCTET_STRING, dt.DOMAIN):
        return value.encode("utf-8") if isinstance(value, str) else bytes(value)
    if var.data_type == dt.BOOLEAN:
        return b"\x01" if value else b"\x00"
    st = od.ODVariable.STRUCT_TYPES[var.data_type or 0]
    if var.data_type in dt.FLOAT_TYPES:
        return st.pack(float(value))
    v = int(value)
    bits = 8 * st.size
    if is_signed(var):
        v = (v + (1 << (bits - 1))) % (1 << bits) - (1 << (bits - 1))
    else:
        v &= (1 << bits) - 1
    return st.pack(v)


def decode(var: od.ODVariable, data: bytes) -> Any:
    """The value of ``data`` (exactly the type's size for fixed-size types)."""
    if var.data_type == dt.VISIBLE_STRING:
        return data.decode("utf-8", errors="replace")
    if var.data_type == dt.UNICODE_STRING:
        return data.decode("utf_16_le", errors="replace")
    if var.data_type in (dt.OCTET_STRING, dt.DOMAIN):
        return bytes(data)
    if var.data_type == dt.BOOLEAN:
        return 1 if data[0] else 0
    (value,) = od.ODVariable.STRUCT_TYPES[var.data_type or 0].unpack(data)
    return value


def to_bits(var: od.ODVariable | None, value: Any, bits: int) -> int:
    """``value`` as an unsigned integer of ``bits`` bits, for packing into a PDO."""
    if var is None:
        return 0
    if isinstance(value, (str, bytes, bytearray)) or var.data_type in dt.FLOAT_TYPES:
        raw = encode(var, value)
        return int.from_bytes(raw[: (bits + 7) // 8].ljust((bits + 7) // 8, b"\0"), "little") & (
            (1 << bits) - 1
        )
    return int(value) & ((1 << bits) - 1)


def from_bits(var: od.ODVariable, raw: int, bits: int) -> Any:
    """Inverse of :func:`to_bits`: the value of ``var`` carried in ``bits`` bits of a PDO."""
    if var.data_type in _STRING_TYPES or var.data_type in dt.FLOAT_TYPES:
        return decode(var, raw.to_bytes((bits + 7) // 8, "little"))
    if is_signed(var) and raw & (1 << (bits - 1)):
        return raw - (1 << bits)
    return raw


@dataclass
class PersistentStore:
    """Non-volatile memory of a device: what 1010h "save" stored, what LSS "store" stored.

    Survives ``SimNode.power_cycle()``; give the same store to a new SimNode to simulate a
    replaced process with the same device. ``values`` holds only parameters that differ from
    the EDS default at the time of saving; ``node_id`` is a stored node id (None: configured).
    """

    values: dict[tuple[int, int], Any] = field(default_factory=dict)
    node_id: int | None = None
    bitrate_index: int | None = None
    position_offset: int | None = None  # calibration (position - model) at the last save
    saves: int = 0


def _ranges(which: int) -> tuple[tuple[int, int], ...]:
    """Index ranges of the 1010h/1011h sub-indices (SGH10 manual 4.7.2.11 / 4.7.2.12)."""
    return {
        1: ((0x1000, 0xFFFF),),  # all parameters
        2: ((0x1000, 0x1FFF),),  # communication parameters (DS-301)
        3: ((0x6000, 0x9FFF),),  # application parameters (device profile)
        4: ((0x2000, 0x5FFF),),  # manufacturer-specific parameters
    }.get(which, ((0x1000, 0xFFFF),))


def in_ranges(index: int, which: int) -> bool:
    return any(lo <= index <= hi for lo, hi in _ranges(which))


class ObjectValues:
    """The (index, sub) -> value dict of a node, typed by its EDS."""

    def __init__(
        self, dictionary: od.ObjectDictionary, given: dict[tuple[int, int], Any] | None = None
    ) -> None:
        self.od = dictionary
        #: values the file gives outside the objects' own sections (1018h from [DeviceInfo]),
        #: in place of their defaults
        self.given = dict(given or {})
        self.vars: dict[tuple[int, int], od.ODVariable] = {}
        self.values: dict[tuple[int, int], Any] = {}
        for entry in dictionary.values():
            if isinstance(entry, od.ODVariable):
                self.vars[(entry.index, 0)] = entry
            else:
                for sub in entry.subindices.values():
                    self.vars[(sub.index, sub.subindex)] = sub

    # -- lookup ------------------------------------------------------------------------------
    def var(self, index: int, sub: int) -> od.ODVariable:
        """The EDS entry, or SdoAbortError 0x06020000 (no object) / 0x06090011 (no sub)."""
        v = self.vars.get((index, sub))
        if v is not None:
            return v
        if index not in self.od:
            raise SdoAbortError(ABORT_NO_OBJECT, f"0x{index:04X} not in the object dictionary")
        raise SdoAbortError(ABORT_NO_SUB, f"{ObjRef(index, sub)} has no such sub-index")

    def has(self, index: int, sub: int = 0) -> bool:
        return (index, sub) in self.vars

    def get(self, index: int, sub: int = 0, default: Any = None) -> Any:
        return self.values.get((index, sub), default)

    def set(self, index: int, sub: int, value: Any) -> None:
        self.values[(index, sub)] = value

    def keys(self) -> Iterator[tuple[int, int]]:
        return iter(self.vars)

    # -- (re)initialisation ------------------------------------------------------------------
    def load_defaults(self, node_id: int, store: PersistentStore, index_range: int = 1) -> None:
        """Set every object of the 1011h-style range to EDS default, then stored value."""
        for key, var in self.vars.items():
            if not in_ranges(key[0], index_range):
                continue
            default = self.given[key] if key in self.given else resolve_default(var, node_id)
            self.values[key] = store.values.get(key, default)

    def save(self, node_id: int, store: PersistentStore, index_range: int = 1) -> None:
        """1010h: store writable parameters of the range that differ from the EDS default."""
        for key, var in self.vars.items():
            if not in_ranges(key[0], index_range) or key[0] in (0x1010, 0x1011):
                continue
            if not var.writable:
                continue
            value = self.values.get(key)
            if value == self.given.get(key, resolve_default(var, node_id)):
                store.values.pop(key, None)
            else:
                store.values[key] = value
        store.saves += 1

    @staticmethod
    def restore(store: PersistentStore, index_range: int = 1) -> None:
        """1011h: forget stored values of the range (defaults apply after the next reset)."""
        for key in [k for k in store.values if in_ranges(k[0], index_range)]:
            del store.values[key]

    # -- SDO-level access --------------------------------------------------------------------
    def read_bytes(self, index: int, sub: int) -> bytes:
        var = self.var(index, sub)
        if not var.readable:
            raise SdoAbortError(ABORT_WRITE_ONLY, f"{ObjRef(index, sub)} is write-only")
        return encode(var, self.values.get((index, sub), resolve_default(var, 0)))

    def check_write(
        self, index: int, sub: int, data: bytes, size_given: bool
    ) -> tuple[od.ODVariable, Any]:
        """Access, length and range checks of a download; returns (var, decoded value)."""
        var = self.var(index, sub)
        if not var.writable:
            raise SdoAbortError(ABORT_READ_ONLY, f"{ObjRef(index, sub)} is read-only")
        size = type_size(var)
        if size is not None:
            if len(data) != size:
                if size_given or len(data) < size:
                    raise SdoAbortError(
                        ABORT_LENGTH, f"{ObjRef(index, sub)} takes {size} bytes, got {len(data)}"
                    )
                data = data[:size]
        value = decode(var, data)
        if var.data_type in dt.NUMBER_TYPES:
            if (var.min is not None and value < var.min) or (
                var.max is not None and value > var.max
            ):
                raise SdoAbortError(
                    ABORT_RANGE, f"{ObjRef(index, sub)} value {value} outside {var.min}..{var.max}"
                )
        return var, value
