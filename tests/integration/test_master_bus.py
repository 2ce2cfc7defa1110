"""The CAN bus under the gateway: a backend that fails is reopened with backoff while the gateway
keeps running; controller error frames (error passive, bus off) surface in the health status."""

from __future__ import annotations

import can
import pytest

from canopen_gateway.bus.driver import BusDriver
from canopen_gateway.errors import BusDown
from canopen_gateway.image import ProcessImage
from tests.helpers import master_running as running
from tests.helpers import node_operational as operational
from tests.helpers import unique_channel, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


def error_frame(cls: int, ctrl: int = 0) -> can.Message:
    """An error frame in the linux/can/error.h layout: class in the CAN-ID, status in byte 1."""
    return can.Message(
        arbitration_id=cls,
        is_error_frame=True,
        is_extended_id=False,
        data=bytes([0, ctrl, 0, 0, 0, 0, 0, 0]),
    )


async def test_bus_shut_under_the_driver_is_reopened_and_decoding_resumes() -> None:
    async with running([WIRE], can={"reopen_backoff_s": 1.5}) as gw:
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        assert gw.driver.bus is not None
        gw.driver.bus.shutdown()  # the backend dies under the reader: recv() raises
        await wait_until(lambda: gw.driver.state == "down", 2, "bus reported down")
        assert gw.status()["bus"]["state"] == "down"
        assert not gw.status()["ready"]
        assert "receive failed" in gw.driver.last_error
        # while it is down, commands fail fast with a typed error
        with pytest.raises(BusDown):
            await gw.commands.nmt("wire", "start")
        with pytest.raises(BusDown):
            await gw.commands.sdo_read("wire", "0x1000:00")
        with pytest.raises(BusDown):
            await gw.commands.scan_bus()
        await wait_until(lambda: gw.driver.state == "ok", 3, "bus reopened")
        assert gw.driver.reopens == 1
        assert gw.image.counters["bus_errors"] >= 1
        seq = gw.image.nodes["wire"].signals["position"].seq
        await wait_until(lambda: gw.image.nodes["wire"].signals["position"].seq > seq + 3, 3, "TPDOs decoded again")
        assert gw.status()["ready"]
        # 1.5 s without heartbeats: the node was lost, and is found and configured again
        assert gw.image.nodes["wire"].health.loss_count == 1
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational again")
        assert await gw.commands.sdo_read("wire", "0x1018:01") == 0x195


async def test_error_passive_and_bus_off_surface_in_health_until_the_controller_recovers() -> None:
    async with running([], simulate={"nodes": []}) as gw:
        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            bus.send(error_frame(0x04, 0x20))  # CAN_ERR_CRTL, TX passive
            await wait_until(lambda: gw.driver.state == "error", 2, "error passive")
            status = gw.status()
            assert status["bus"] == {"state": "error", "detail": "error passive (transmit)"}
            assert not status["ready"]
            bus.send(error_frame(0x04, 0x40))  # CAN_ERR_CRTL_ACTIVE: error active again
            await wait_until(lambda: gw.driver.state == "ok", 2, "error active again")
            bus.send(error_frame(0x40))  # CAN_ERR_BUSOFF
            await wait_until(lambda: gw.driver.last_error == "bus off", 2, "bus off")
            assert gw.driver.state == "error"
            bus.send(error_frame(0x100))  # CAN_ERR_RESTARTED
            await wait_until(lambda: gw.driver.state == "ok", 2, "controller restarted")
            assert gw.image.counters["bus_errors"] == 4
        finally:
            bus.shutdown()


async def test_error_state_clears_when_frames_flow_without_error_frames_for_the_hold_time() -> None:
    async with running([WIRE]) as gw:
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        gw.driver.controller.error_hold_s = 0.2
        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            bus.send(error_frame(0x04, 0x10))  # RX passive; no "active" frame will follow
            await wait_until(lambda: gw.driver.state == "error", 2, "error passive")
            # the hold time itself is checked on a fake clock (tests/unit/test_bus_clock.py)
            await wait_until(lambda: gw.driver.state == "ok", 2, "ok again (hold time)")
        finally:
            bus.shutdown()


async def test_backend_that_cannot_open_is_retried_with_doubling_backoff() -> None:
    image = ProcessImage()
    # no SocketCAN interface of that name here (or no SocketCAN at all): opening raises OSError
    driver = BusDriver(
        {"interface": "socketcan", "channel": "gw-no-such-if"}, image, reopen_backoff_s=0.02
    )
    driver.open()  # does not raise: the reader keeps trying
    try:
        assert driver.state == "down"
        assert image.bus_state == "down"
        await wait_until(lambda: driver.reopen_attempts >= 3, 3, "three reopen attempts")
        assert "reopen failed" in driver.last_error
        assert [driver.backoff_s(n) for n in (1, 2, 3)] == [0.02, 0.04, 0.08]
        assert driver.backoff_s(20) == 30.0  # capped
        with pytest.raises(can.CanError):
            driver.send(0x000, b"\x01\x00")
    finally:
        driver.close()


def test_unknown_interface_name_is_a_configuration_error_at_open() -> None:
    driver = BusDriver(
        {"interface": "no-such-interface", "channel": unique_channel()}, ProcessImage()
    )
    with pytest.raises(can.CanInterfaceNotImplementedError):
        driver.open()
