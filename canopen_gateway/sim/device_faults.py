"""The faults of one simulated device: which are active, and what a fault the device's features
do not implement does (the sim hint ``faults:``).

``DeviceFaults(host)`` belongs to one ``SimNode`` (seen as ``FaultHost``, a Protocol). A fault
is offered to every feature first (``SimFeature.on_fault``); without one, a fault listed in the
sim hint ``faults: {name: {emcy: code, register: bits, alarm_bit: n}}`` raises / clears that
EMCY and sets / clears bit n of the DS-406 alarms 6503h (default for ``sensor_error``: bit 0,
position error, SGH10 manual 4.7.2.38). Power-on clears every fault; after a reset node or
reset communication the device still has its faults and shows them again.

Imports: the standard library; sim.features, sim.hints and sim.objects for types only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from canopen_gateway.sim.features import SimFeature
    from canopen_gateway.sim.hints import SimHints
    from canopen_gateway.sim.objects import ObjectValues

#: DS-406 6503h alarms: the bit a ``sensor_error`` sets when its hint names none (SGH10 manual
#: 4.7.2.38: bit 0, position error)
SENSOR_ERROR_ALARM_BIT = 0


class FaultHost(Protocol):
    """What the device's faults use of their node."""

    values: ObjectValues
    hints: SimHints
    features: list[SimFeature]

    def raise_emcy(self, code: int, register: int = 0, mfr: bytes = b"", now: float | None = None) -> None: ...
    def clear_emcy(self, code: int, now: float | None = None) -> None: ...


class DeviceFaults:
    """The active faults of one simulated device and the hint faults' EMCY and alarm bits."""

    def __init__(self, host: FaultHost) -> None:
        self.host = host
        self.active: dict[str, bool] = {}

    def clear(self) -> None:
        """Power-on: no fault."""
        self.active.clear()

    def show_again(self) -> None:
        """After a reset node / communication: the alarm bits of the faults still active."""
        for name, active in self.active.items():
            if active:
                self.alarm_bits(name, True)

    def inject(self, name: str, active: bool, now: float) -> bool:
        """Turn a fault on/off; True if a feature or the sim hint ``faults:`` implements it."""
        host = self.host
        self.active[name] = active
        handled = False
        for b in host.features:
            handled = b.on_fault(name, active, now) or handled
        if not handled:
            spec = host.hints.faults.get(name)
            if spec and "emcy" in spec:
                self.alarm_bits(name, active)
                code = int(spec["emcy"])
                if active:
                    host.raise_emcy(code, int(spec.get("register", 0)), now=now)
                else:
                    host.clear_emcy(code, now=now)
                handled = True
        return handled

    def alarm_bits(self, name: str, active: bool) -> None:
        """Set / clear the hint fault's bit of the DS-406 alarms 6503h."""
        spec = self.host.hints.faults.get(name) or {}
        alarm_bit = spec.get("alarm_bit", SENSOR_ERROR_ALARM_BIT if name == "sensor_error" else None)
        values = self.host.values
        if alarm_bit is not None and values.has(0x6503, 0):
            alarms = int(values.get(0x6503, 0, 0))
            mask = 1 << int(alarm_bit)
            values.set(0x6503, 0, alarms | mask if active else alarms & ~mask)
