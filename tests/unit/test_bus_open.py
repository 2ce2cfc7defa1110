"""The one line for a CAN bus that cannot be opened (``canopen_gateway.tools.bus_open``): the settings,
the reason as the OS or the backend gave it, and what usually causes it, for the failures this
machine cannot produce for real (no such device, interface down, a vendor library missing)."""

from __future__ import annotations

import errno
import os

import pytest

from canopen_gateway.config import Config
from canopen_gateway.tools.bus_open import BusOpenError, bus_open_line, opening
from tests.helpers import parse_checked_config

NODES = [{"name": "wire", "node_id": 1, "profile": "sgh10"}]


def config(**can: object) -> Config:
    return parse_checked_config({"can": can, "nodes": NODES}, "plant.yaml", environ={})


def test_no_such_device_says_check_the_adapter_and_its_driver() -> None:
    cfg = config(interface="socketcan", channel="can0")
    line = bus_open_line(cfg, OSError(errno.ENODEV, os.strerror(errno.ENODEV)))
    assert line == (
        "error: plant.yaml: can.interface: socketcan, can.channel: can0: the CAN bus cannot be "
        "opened: No such device (errno 19); no such device: is the adapter plugged in and its "
        "driver module loaded (ip link show can0)?"
    )


def test_an_interface_that_is_down_gets_the_command_that_brings_it_up() -> None:
    cfg = config(interface="socketcan", channel="can1", bitrate=250000)
    line = bus_open_line(cfg, OSError(errno.ENETDOWN, os.strerror(errno.ENETDOWN)))
    assert line.endswith(
        "(errno 100); the interface is down: ip link set can1 up type can bitrate 250000"
    )


def test_a_missing_vendor_library_is_named() -> None:
    cfg = config(interface="pcan", channel="PCAN_USBBUS1")
    line = bus_open_line(cfg, OSError("pcanbasic library not found."))
    assert line.startswith(
        "error: plant.yaml: can.interface: pcan, can.channel: PCAN_USBBUS1: the CAN bus cannot "
        "be opened: pcanbasic library not found.; the driver library is missing: "
    )
    assert "PCAN-Basic" in line


def test_the_variable_that_set_the_interface_is_named() -> None:
    cfg = parse_checked_config(
        {"can": {"interface": "virtual", "channel": "x"}, "nodes": NODES},
        "plant.yaml",
        environ={"CANOPEN_GATEWAY__CAN__INTERFACE": "socketcan"},
    )
    line = bus_open_line(cfg, OSError(errno.EAFNOSUPPORT, "Address family not supported"))
    assert line.startswith("error: CANOPEN_GATEWAY__CAN__INTERFACE: can.interface: socketcan")


def test_opening_turns_any_failure_of_the_open_into_the_line() -> None:
    cfg = config(interface="socketcan", channel="can9")
    with pytest.raises(BusOpenError) as exc, opening(cfg):
        raise ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused")
    assert "Connection refused (errno 111); nothing listens there" in exc.value.line
