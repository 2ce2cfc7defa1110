"""Whether the configured python-can interface (``can.interface``) can be opened by name.

python-can finds a backend by name in ``can.interfaces.BACKENDS`` (its own ones plus the
plug-ins registered as ``can.interface`` entry points, e.g. ``remote`` from python-can-remote)
and imports its module only when a bus is opened. An unknown or uninstalled name then fails
deep inside ``can.Bus(...)``; ``interface_problem`` says the same thing up front, in one line,
naming the interface and the ones that are installed, so ``check`` and ``run`` can refuse the
config before anything starts.

``driver_problem`` says when the vendor library a backend needs is missing (PCAN-Basic,
Kvaser CANlib, pyserial): python-can finds that out only when the bus
opens, and the gateway would retry forever. ``can_section_problems`` checks the keys of the
``can:`` section against the parameters of the interface's bus class (its signature and its
documented ``:param`` names, plus python-can's common keys): a typo is an error naming the
nearest key, instead of a key python-can ignores.

``open_can_bus`` opens the configured bus: ``can.Bus(**can)``, except for ``interface:
socketcand``, which gets ``canopen_gateway.bus.socketcand_bus.SocketcandBus`` (python-can's own
socketcand bus never reports a lost connection: the one place we make up for it).

Imports: python-can, bus.socketcand_bus and the standard library only. Apart from
``open_can_bus``, opens no bus and touches no hardware (it loads a backend's driver library to
see that it is there, and opens no channel).
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import can.interfaces
import can.typechecking
from can.exceptions import CanInterfaceNotImplementedError

#: Keys python-can reads for every interface (``can.Bus`` and ``can.util.load_config``), the
#: bit timing fields it turns into ``timing``, and our own key (the reopen delay).
TIMING_KEYS = frozenset(
    set(can.typechecking.BitTimingDict.__annotations__)
    | set(can.typechecking.BitTimingFdDict.__annotations__)
)
COMMON_KEYS = frozenset(
    {"interface", "channel", "bitrate", "data_bitrate", "fd", "timing", "can_filters"}
    | TIMING_KEYS
    | {"reopen_backoff_s"}
)


@contextmanager
def quiet_imports(level: int = logging.ERROR) -> Iterator[None]:
    """python-can's backends log warnings while they import ("Kvaser canlib is unavailable",
    "uptime library not available"): our own line says what matters. ``level``: the least
    level still logged meanwhile."""
    logger = logging.getLogger("can")
    before = logger.level
    logger.setLevel(level)
    try:
        yield
    finally:
        logger.setLevel(before)


def bus_class(interface: str) -> type[can.BusABC]:
    """The bus class python-can opens for ``interface``, found the way ``can.Bus`` finds it
    (``can.interfaces.BACKENDS``, then the module's class). Raises NotImplementedError for an
    unknown name, CanInterfaceNotImplementedError when its module or class does not import."""
    try:
        module_name, class_name = can.interfaces.BACKENDS[interface]
    except KeyError:
        raise NotImplementedError(f"CAN interface '{interface}' not supported") from None
    try:
        module = importlib.import_module(module_name)
    except Exception as exc:  # noqa: BLE001 - any import failure makes the interface unusable
        raise CanInterfaceNotImplementedError(
            f"Cannot import module {module_name} for CAN interface '{interface}': {exc}"
        ) from None
    try:
        cls: type[can.BusABC] = getattr(module, class_name)
    except Exception as exc:  # noqa: BLE001
        raise CanInterfaceNotImplementedError(
            f"Cannot import class {class_name} from module {module_name} for CAN interface "
            f"'{interface}': {exc}"
        ) from None
    return cls


def installed_interfaces() -> list[str]:
    """The interface names python-can knows on this install, sorted."""
    return sorted(can.interfaces.VALID_INTERFACES)


def interface_problem(interface: str) -> str | None:
    """None when python-can can load ``interface``; else what is wrong and what is allowed."""
    installed = ", ".join(installed_interfaces())
    if interface not in can.interfaces.BACKENDS:
        # a misspelt name (virtul): the nearest installed one first, as for misspelt keys
        near = difflib.get_close_matches(str(interface), list(can.interfaces.BACKENDS), n=1, cutoff=0.6)
        hint = f"did you mean {near[0]!r}? " if near else ""
        return (
            f"unknown CAN interface {interface!r} (not installed); {hint}"
            f"installed python-can interfaces: {installed}"
        )
    try:
        with quiet_imports():
            bus_class(interface)
    except (CanInterfaceNotImplementedError, NotImplementedError, ImportError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return (
            f"CAN interface {interface!r} is not usable on this install ({reason}); "
            f"installed python-can interfaces: {installed}"
        )
    return None


_PARAM = re.compile(r":param\s+(?:[\w\[\], .|]+\s)?(\w+):")


def interface_keys(interface: str) -> frozenset[str] | None:
    """The ``can:`` keys the interface's bus class takes; None when it cannot be inspected."""
    try:
        with quiet_imports():
            cls = bus_class(interface)
    except Exception:  # noqa: BLE001 - reported by interface_problem
        return None
    params = set()
    for klass in cls.__mro__:
        if klass is can.BusABC or klass is object:
            break
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        params |= {
            name
            for name, p in inspect.signature(init).parameters.items()
            if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL) and name != "self"
        }
        params |= set(_PARAM.findall((init.__doc__ or "") + (klass.__doc__ or "")))
    return frozenset(params - {"kwargs", "config"}) | COMMON_KEYS


def can_section_problems(section: dict[str, Any]) -> list[tuple[str, str]]:
    """``(key path, problem)`` for every key of ``can:`` the configured interface does not take."""
    interface = str(section.get("interface", "virtual"))
    allowed = interface_keys(interface)
    if allowed is None:
        return []
    out = []
    for key in section:
        if key in allowed:
            continue
        near = difflib.get_close_matches(key, sorted(allowed), n=1, cutoff=0.6)
        hint = f"did you mean {near[0]!r}? " if near else ""
        listed = sorted(allowed - TIMING_KEYS - {"reopen_backoff_s"}) + ["reopen_backoff_s"]
        out.append(
            (
                f"can.{key}",
                f"unknown key for interface {interface!r} ({hint}it takes: "
                + ", ".join(listed)
                + ", and python-can's bit timing keys)",
            )
        )
    return out


def _pcan() -> str | None:
    from can.interfaces.pcan.basic import PCANBasic

    try:
        PCANBasic()  # loads the library; opens no channel
    except OSError as exc:
        return (
            f"PEAK's PCAN-Basic library is not installed ({exc}); install PCAN-Basic for Linux, "
            "or use interface: socketcan with the kernel's peak_usb driver"
        )
    return None


def _kvaser() -> str | None:
    mod = importlib.import_module("can.interfaces.kvaser.canlib")
    if getattr(mod, "__canlib", None) is None:
        return "Kvaser CANlib (libcanlib.so) is not installed; install Kvaser's Linux drivers and SDK"
    return None


def _pyserial() -> str | None:
    try:
        importlib.import_module("serial")
    except ImportError:
        return "it needs pyserial, which is not installed (pip install pyserial)"
    return None


#: Interface -> check of the driver library its bus needs when it opens.
_DRIVER_CHECKS = {
    "pcan": _pcan,
    "kvaser": _kvaser,
    "slcan": _pyserial,
    "serial": _pyserial,
    "robotell": _pyserial,
    "seeedstudio": _pyserial,
}


def driver_problem(interface: str) -> str | None:
    """None when the driver library the interface needs is there (or no check is known)."""
    check = _DRIVER_CHECKS.get(interface)
    if check is None:
        return None
    with quiet_imports():
        try:
            return check()
        except ImportError as exc:
            return f"its python-can module cannot be loaded ({exc})"


def open_can_bus(bus_kwargs: dict[str, Any]) -> can.BusABC:
    """Open the bus of the ``can:`` section: ``can.Bus(**can)``, but ``interface: socketcand``
    gets our ``SocketcandBus`` (same keys), whose receive raises when the server closed the
    connection and whose open does not retry by itself (python-can's spins on both)."""
    if bus_kwargs.get("interface") == "socketcand":
        from canopen_gateway.bus.socketcand_bus import SocketcandBus

        kwargs = {k: v for k, v in bus_kwargs.items() if k != "interface"}
        return SocketcandBus(**kwargs)
    return can.Bus(**bus_kwargs)
