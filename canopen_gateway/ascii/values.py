"""The CiA 309-3 data types and their text form, sans-I/O: the type names (``b``, ``i8`` ..
``u64``, ``x8`` .. ``x64``, ``r32``, ``r64``, ``vs``, ``os``, ``d``), a value's text into the
bytes of an SDO download (``encode_value``) and an upload's bytes into text (``format_value``).

Imports: the standard library. Nothing of bus/, commands or a transport.
"""

from __future__ import annotations

import base64
import binascii
import math
import re
import struct
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class DataType:
    """A CiA 309-3 data type: its name, its ``struct`` format (None: variable length) and how
    its value is written as text."""

    name: str
    fmt: str | None
    kind: str  # "bool" | "int" | "hex" | "real" | "vs" | "b64"

    @property
    def size(self) -> int | None:
        return None if self.fmt is None else struct.calcsize(self.fmt)


#: The data types of CiA 309-3 this gateway speaks (``x8``..``x64``: unsigned, hex text).
DATA_TYPES: dict[str, DataType] = {
    t.name: t
    for t in (
        DataType("b", "<B", "bool"),
        DataType("i8", "<b", "int"),
        DataType("i16", "<h", "int"),
        DataType("i32", "<i", "int"),
        DataType("i64", "<q", "int"),
        DataType("u8", "<B", "int"),
        DataType("u16", "<H", "int"),
        DataType("u32", "<I", "int"),
        DataType("u64", "<Q", "int"),
        DataType("x8", "<B", "hex"),
        DataType("x16", "<H", "hex"),
        DataType("x32", "<I", "hex"),
        DataType("x64", "<Q", "hex"),
        DataType("r32", "<f", "real"),
        DataType("r64", "<d", "real"),
        DataType("vs", None, "vs"),
        DataType("os", None, "b64"),
        DataType("d", None, "b64"),
    )
}
#: Types of CiA 309-3 this gateway does not speak: ERROR:100, not a syntax error.
UNSUPPORTED_TYPES = frozenset({"t", "td", "us"})


class LengthMismatch(ValueError):
    """The device's bytes do not have the length of the requested data type."""


_INT_RE = re.compile(r"^[+-]?(0[xX][0-9A-Fa-f]+|[0-9]+)$")


def parse_int(text: str) -> int:
    """A decimal or ``0x`` hexadecimal integer (leading zeros allowed); ValueError otherwise."""
    if not _INT_RE.match(text):
        raise ValueError(f"not a number: {text!r}")
    sign = -1 if text.startswith("-") else 1
    body = text.lstrip("+-")
    return sign * (int(body, 16) if body[:2].lower() == "0x" else int(body, 10))


def encode_value(dtype: DataType, text: str) -> bytes:
    """The bytes of an SDO download for ``text`` written as ``dtype``; ValueError when the text
    is not a value of that type (answered ERROR:101)."""
    if dtype.kind in ("bool", "int", "hex"):
        v = parse_int(text)
        if dtype.kind == "bool" and v not in (0, 1):
            raise ValueError("a boolean is 0 or 1")
        try:
            return struct.pack(dtype.fmt or "", v)
        except struct.error:
            raise ValueError(f"{text} does not fit {dtype.name}") from None
    if dtype.kind == "real":
        try:
            f = float(text)
        except ValueError:
            raise ValueError(f"not a number: {text!r}") from None
        try:
            return struct.pack(dtype.fmt or "", f)
        except (struct.error, OverflowError):
            raise ValueError(f"{text} does not fit {dtype.name}") from None
    if dtype.kind == "vs":
        if not text:
            raise ValueError("an empty string cannot be downloaded")
        if any(not 0x20 <= ord(c) <= 0x7E for c in text):
            raise ValueError("a visible string holds printable ASCII characters only")
        return text.encode("ascii")
    # os, d: MIME base64 (RFC 2045) on one line
    try:
        data = base64.b64decode(text.encode("ascii"), validate=True)
    except (binascii.Error, UnicodeEncodeError):
        raise ValueError("not base64") from None
    if not data:
        raise ValueError("an empty value cannot be downloaded")
    return data


def _shortest_float(v: float, fmt: str) -> str:
    """The shortest decimal text that packs back to the same bytes as ``v``."""
    if math.isnan(v) or math.isinf(v):
        return repr(v)
    packed = struct.pack(fmt, v)
    for digits in range(1, 18):
        text = f"{v:.{digits}g}"
        if struct.pack(fmt, float(text)) == packed:
            return text
    return repr(v)


def _pack_single(v: float) -> bytes:
    """``v`` as a single, or infinity's bytes when it is out of a single's range."""
    try:
        return struct.pack("<f", v)
    except OverflowError:
        return struct.pack("<f", math.inf)


def quote_vs(text: str) -> str:
    """A visible string as a token: bare when it is one word, else in double quotes (a quote
    inside doubled)."""
    if text and not any(c in text for c in ' \t"#') and not text.startswith("["):
        return text
    return '"' + text.replace('"', '""') + '"'


def format_value(dtype: DataType, data: bytes) -> str:
    """The text of an SDO upload's bytes as ``dtype`` (raises LengthMismatch)."""
    size = dtype.size
    if size is not None:
        if len(data) < size or any(data[size:]):
            raise LengthMismatch(f"{len(data)} bytes for {dtype.name}")
        data = data[:size]  # an expedited upload without size indication is 4 bytes long
        (v,) = struct.unpack(dtype.fmt or "", data)
        if dtype.kind == "hex":
            return f"0x{v:0{2 * size}X}"
        if dtype.kind == "real":
            return _shortest_float(v, dtype.fmt or "")
        return str(v)
    if dtype.kind == "vs":
        text = data.rstrip(b"\0").decode("ascii", errors="replace").replace("\ufffd", "?")
        return quote_vs("".join(c if 0x20 <= ord(c) <= 0x7E else "?" for c in text))
    return base64.b64encode(data).decode("ascii")


def format_plain(value: Any) -> str:
    """A value decoded by the command service from the object's EDS type (a read without a
    type): integers in decimal (a TIME_OF_DAY / TIME_DIFFERENCE: its 48-bit word), reals,
    visible strings, anything else as base64."""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        # a REAL32 is exactly a single; a REAL64 that is not gets the digits of a double
        single = math.isnan(value) or struct.unpack("<f", _pack_single(value))[0] == value
        return _shortest_float(value, "<f" if single else "<d")
    if isinstance(value, str):
        return quote_vs("".join(c if 0x20 <= ord(c) <= 0x7E else "?" for c in value))
    return base64.b64encode(bytes(value)).decode("ascii")
