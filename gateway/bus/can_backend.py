"""Whether the configured python-can interface (``can.interface``) can be opened by name.

python-can finds a backend by name in ``can.interfaces.BACKENDS`` (its own ones plus the
plug-ins registered as ``can.interface`` entry points, e.g. ``remote`` from python-can-remote)
and imports its module only when a bus is opened. An unknown or uninstalled name then fails
deep inside ``can.Bus(...)``; ``interface_problem`` says the same thing up front, in one line,
naming the interface and the ones that are installed, so ``check`` and ``run`` can refuse the
config before anything starts.

Imports: python-can only. Opens no bus and touches no hardware (a backend's driver library is
loaded when a bus opens, not here).
"""

from __future__ import annotations

import can.interface
import can.interfaces
from can.exceptions import CanInterfaceNotImplementedError


def installed_interfaces() -> list[str]:
    """The interface names python-can knows on this install, sorted."""
    return sorted(can.interfaces.VALID_INTERFACES)


def interface_problem(interface: str) -> str | None:
    """None when python-can can load ``interface``; else what is wrong and what is allowed."""
    installed = ", ".join(installed_interfaces())
    if interface not in can.interfaces.BACKENDS:
        return (
            f"unknown CAN interface {interface!r} (not installed); "
            f"installed python-can interfaces: {installed}"
        )
    try:
        can.interface._get_class_for_interface(interface)
    except (CanInterfaceNotImplementedError, NotImplementedError, ImportError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return (
            f"CAN interface {interface!r} is not usable on this install ({reason}); "
            f"installed python-can interfaces: {installed}"
        )
    return None
