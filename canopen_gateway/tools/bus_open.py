"""A bus that cannot be opened, as one line: the one place every command that opens the CAN bus
(run, simulate, scan, monitor, sdo, nmt, lss) turns python-can's failure into words.

python-can raises whatever its backend raises when ``can.Bus(**can)`` fails: an ``OSError``
with the kernel's errno for SocketCAN (97 no AF_CAN in this kernel, 19 no such device, 100
interface down), ``ConnectionRefusedError`` for a ``remote`` server nobody runs, an ``OSError``
without errno for a vendor library that is missing, ``CanInterfaceNotImplementedError`` or a
``NameError`` for a backend whose module cannot load. ``BusOpenError.line`` names the settings
(``can.interface``, ``can.channel``, and the host/port keys the backend takes), the reason the
OS or the backend gave, and what usually causes it; the command line prints it and exits 2.

``open_bus(cfg)`` opens the configured bus (a ``can.BusABC`` of the tool's own);
``opening(cfg)`` wraps a block that opens it (the simulated devices' connection);
``gateway_bus(cfg)`` wraps the start of a gateway or a commissioning master that must open its
bus (``Gateway(..., bus_must_open=True)``: it opens the bus once and stops when it cannot; a bus
lost later is reopened by its driver, ``canopen_gateway.bus.driver``).

Imports: python-can, canopen_gateway.config (blame), canopen_gateway.bus.can_backend (quiet_imports,
driver_problem, open_can_bus), canopen_gateway.bus.driver (BusOpenFailed), canopen_gateway.bus.network
(NetworkOpenFailed: which network's bus).
"""

from __future__ import annotations

import errno
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from canopen_gateway.bus.can_backend import driver_problem, open_can_bus, quiet_imports
from canopen_gateway.bus.driver import BusOpenFailed
from canopen_gateway.bus.network import NetworkOpenFailed
from canopen_gateway.config import Config, blame

#: What usually causes an errno of opening a CAN interface, in words (``{channel}`` and
#: ``{bitrate}`` are filled in from the config).
_ERRNO_HINT = {
    errno.EAFNOSUPPORT: "this kernel has no SocketCAN (AF_CAN): load its module (modprobe can_raw) "
    "or choose another can.interface",
    errno.ENODEV: "no such device: is the adapter plugged in and its driver module loaded "
    "(ip link show {channel})?",
    errno.ENXIO: "no such device: is the adapter plugged in and its driver module loaded?",
    errno.ENOENT: "no such device file: is the adapter plugged in?",
    errno.ENETDOWN: "the interface is down: ip link set {channel} up type can bitrate {bitrate}",
    errno.ECONNREFUSED: "nothing listens there: start the CAN server or correct the address",
    errno.EHOSTUNREACH: "that host cannot be reached: correct the address",
    errno.EACCES: "not allowed for this user (permissions of the device)",
    errno.EPERM: "not allowed for this user (permissions of the device)",
    errno.EBUSY: "the device is in use by another program",
}

#: python-can backends that reach their bus over the network (the address keys they take).
_ADDRESS_KEYS = ("host", "port")


class BusOpenError(Exception):
    """The configured CAN bus could not be opened; ``line`` says which, why and what to check."""

    def __init__(self, line: str):
        self.line = line
        super().__init__(line)


def _settings(cfg: Config) -> str:
    """``can.interface: socketcan, can.channel: can9`` (plus ``can.host``/``can.port`` when set;
    a network's keys under its ``networks[k].``)."""
    kwargs = cfg.can.bus_kwargs()
    can = cfg.qualify("can")
    parts = [f"{can}.interface: {kwargs.get('interface')}"]
    if kwargs.get("channel") is not None:
        parts.append(f"{can}.channel: {kwargs['channel']}")
    parts += [f"{can}.{k}: {kwargs[k]}" for k in _ADDRESS_KEYS if kwargs.get(k) is not None]
    return ", ".join(parts)


def _reason_and_hint(cfg: Config, exc: BaseException) -> tuple[str, str | None]:
    kwargs = cfg.can.bus_kwargs()
    interface = str(kwargs.get("interface"))
    if isinstance(exc, OSError) and exc.errno:
        hint = _ERRNO_HINT.get(exc.errno)
        reason = f"{exc.strerror or os.strerror(exc.errno)} (errno {exc.errno})"
        if hint is not None:
            hint = hint.format(channel=kwargs.get("channel"), bitrate=kwargs.get("bitrate", 500000))
        return reason, hint
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    if isinstance(exc, TimeoutError):
        return text, "nothing answers there: start the CAN server or correct the address"
    driver = driver_problem(interface)
    if driver is not None:
        return text, f"the driver library is missing: {driver}"
    if isinstance(exc, (ImportError, NotImplementedError, NameError)):
        return text, "the backend's driver library is missing or cannot be loaded"
    return text, None


def bus_open_line(cfg: Config, exc: BaseException) -> str:
    """The one line for a bus of ``cfg`` that raised ``exc`` when it was opened."""
    where = blame(cfg.qualify("can.interface"), cfg.source, cfg.env_keys)
    reason, hint = _reason_and_hint(cfg, exc)
    return (
        f"error: {where}: {_settings(cfg)}: the CAN bus cannot be opened: {reason}"
        + (f"; {hint}" if hint else "")
    )


@contextmanager
def opening(cfg: Config) -> Iterator[None]:
    """Run a block that opens the configured bus; any failure of the open leaves as
    ``BusOpenError``. python-can's backends log while they try (socketcand once per retry):
    the line says what matters."""
    try:
        with quiet_imports(level=logging.CRITICAL):
            yield
    except BusOpenError:
        raise
    except Exception as exc:  # noqa: BLE001 - every backend raises its own kind
        raise BusOpenError(bus_open_line(cfg, exc)) from None


def open_bus(cfg: Config) -> Any:
    """The configured bus, opened for a tool of its own (``can.BusABC``)."""
    with opening(cfg):
        return open_can_bus(cfg.can.bus_kwargs())


@contextmanager
def gateway_bus(cfg: Config) -> Iterator[None]:
    """Run a block that starts a gateway or a commissioning master built with
    ``bus_must_open``: the bus it could not open (``BusOpenFailed``: its own connection or the
    simulated devices') leaves as ``BusOpenError``. The gateway opens its bus once, itself."""
    try:
        yield
    except BusOpenFailed as exc:  # a network's bus: its own can: keys are named
        failed = exc.cfg if isinstance(exc, NetworkOpenFailed) else cfg
        raise BusOpenError(bus_open_line(failed, exc.cause)) from None
