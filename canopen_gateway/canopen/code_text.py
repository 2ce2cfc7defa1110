"""``CodeText``: the base of an enum of numbered protocol codes that each carry their text, so
that a table of codes is written once, number and text on one line (CiA 309-3 internal error
codes ``ascii.grammar.Iec``, CiA 301 NMT commands and their names ``cia301.NmtCommand``).

Imports: the standard library. Nothing of the gateway.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Self


class CodeText(IntEnum):
    """An ``IntEnum`` whose members are written ``NAME = code, "text"``: the member is ``code``
    (compares and packs as that int) and ``member.text`` is ``"text"``."""

    text: str

    def __new__(cls, code: int, text: str) -> Self:
        member = int.__new__(cls, code)
        member._value_ = code
        member.text = text
        return member
