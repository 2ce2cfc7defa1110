"""Signals derived from profile features, not from single objects.

``alphanumeric_display`` (AP05 manual 4.1.2, 5.3.1.2 table 26, 5.3.2 table 27): in the
alpha-numeric display mode a row of text travels in one RPDO, six ASCII characters over bytes
0-5 (set point bytes 0-3 = characters 1-4, bytes 4-5 = characters 5-6), with the control word's
data identifier bit set. ``text_signals`` names one text signal per row, e.g.
``set_point1_text``, so PLCs and cloud apps write a row as one string.

Pure: imports the profile schema only.

Imports: canopen.objref, profiles.schema.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.profiles.schema import Profile, Signal


@dataclass(frozen=True)
class TextSignal:
    name: str
    row: int
    head: str  # signal carrying characters 1-4 (RPDO bytes 0-3)
    tail: str  # signal carrying characters 5-6 (RPDO bytes 4-5)
    control: str  # control word signal
    identifier_bit: int  # control word bit: 0 number, 1 ASCII (AP05 table 27 bit 7)
    length: int

    def as_signal(self, head: Signal) -> Signal:
        return Signal(
            name=self.name,
            object=head.object,
            type="string",
            length=self.length,
            access="rw",
            transport="pdo",
            description=(
                f"Text of display row {self.row} in the alpha-numeric mode: up to {self.length} "
                f"ASCII characters, sent in one RPDO with the data identifier bit set"
            ),
        )


def text_signals(profile: Profile) -> list[TextSignal]:
    feat = profile.features.get("alphanumeric_display")
    if not feat:
        return []
    ctrl_obj = (
        feat.get("control_word")
        or profile.features.get("position_indicator", {}).get("control_word")
        or profile.features.get("guarding_bit", {}).get("control")
    )
    ctrl = profile.signal_for(ObjRef.parse(ctrl_obj)) if ctrl_obj else None
    if ctrl is None:
        return []
    out = []
    for row, spec in sorted((feat.get("rows") or {}).items(), key=lambda kv: int(kv[0])):
        head = profile.signal_for(ObjRef.parse(spec["chars_1_4"]))
        tail = profile.signal_for(ObjRef.parse(spec["chars_5_6"]))
        if head is None or tail is None:
            continue
        out.append(
            TextSignal(
                name=f"{head.name}_text",
                row=int(row),
                head=head.name,
                tail=tail.name,
                control=ctrl.name,
                identifier_bit=int(feat.get("data_identifier_bit", 7)),
                length=int(feat.get("text_length", 6)),
            )
        )
    return out


def text_rows_as_signals(profile: Profile) -> list[Signal]:
    """The text rows as signals (string, rw, RPDO), for listings: the catalogue, the keys."""
    return [t.as_signal(profile.signal(t.head)) for t in text_signals(profile)]
