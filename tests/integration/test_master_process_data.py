"""Process data on a virtual bus: SYNC and heartbeat producers, RTR polling, RPDO encoding, and
frames with an unexpected length or COB-ID counted and ignored."""

from __future__ import annotations

import asyncio
import struct
import time
from typing import Any

import can

from tests.helpers import frame, wait_until
from tests.helpers import master_running as running
from tests.helpers import node_operational as operational


def collect(bus: can.BusABC, match: Any, count: int, timeout_s: float = 3.0) -> list[can.Message]:
    """The first ``count`` frames for which ``match(msg)`` is true (raises on timeout)."""
    out: list[can.Message] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < count:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"only {len(out)} of {count} frames within {timeout_s} s")
        msg = bus.recv(timeout=left)
        if msg is not None and match(msg):
            out.append(msg)
    return out


async def test_sync_and_heartbeat_producers_send_their_frames() -> None:
    """The periods themselves are checked on a fake clock (tests/unit/test_node.py)."""
    async with running(
        [], simulate={"nodes": []}, master={"sync_period_ms": 20, "heartbeat_ms": 100}
    ) as gw:
        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            syncs = await asyncio.to_thread(collect, bus, lambda m: m.arbitration_id == 0x080, 11)
            assert all(m.dlc == 0 for m in syncs)
            beats = await asyncio.to_thread(collect, bus, lambda m: m.arbitration_id == 0x77F, 3)
            assert all(bytes(m.data) == b"\x05" for m in beats)  # node id 127, OPERATIONAL
        finally:
            bus.shutdown()


async def test_rtr_polling_fetches_tpdos_of_a_node_that_sends_none_by_itself() -> None:
    node = {
        "name": "wire",
        "node_id": 1,
        "profile": "sgh10",
        "rtr_poll_ms": 50,
        # TPDO1 timer off (SGH10 manual 4.3: 0 = not sent); no SYNC configured below
        "sdo": [{"object": "0x1800:05", "value": 0}],
    }
    async with running([node], master={"sync_period_ms": 0}) as gw:
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        assert gw.sim.nodes["wire"].get(0x1800, 5) == 0
        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            rtrs = await asyncio.to_thread(
                collect, bus, lambda m: m.arbitration_id == 0x181 and m.is_remote_frame, 2
            )
            assert rtrs[0].dlc == 6  # the mapping's length: position 4 + velocity 2
        finally:
            bus.shutdown()
        seq = gw.image.nodes["wire"].signals["position"].seq
        await wait_until(
            lambda: gw.image.nodes["wire"].signals["position"].seq >= seq + 4, 2, "TPDOs answered to RTR"
        )


async def test_rpdo_carries_the_written_signals_in_the_mapped_layout() -> None:
    node = {"name": "display", "node_id": 1, "profile": "ap05", "guarding_bit": {"enabled": False}}
    async with running([node]) as gw:
        await wait_until(lambda: operational(gw, "display"), 5, "display operational")
        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            await gw.commands.write_signals("display", {"set_point2": 300, "control_word": 0x0200})
            msg = (await asyncio.to_thread(collect, bus, lambda m: m.arbitration_id == 0x301, 1))[0]
        finally:
            bus.shutdown()
        # AP05 manual 5.3.1.3: 301 2C 01 00 00 00 00 00 02
        assert bytes(msg.data) == bytes.fromhex("2C01000000000002")
        sim = gw.sim.nodes["display"]
        await wait_until(lambda: sim.get(0x5F16, 1) == 300, 2, "set point 2 in the device")
        assert sim.get(0x5F0C, 0) == 0x0200


async def test_unknown_cob_id_short_and_long_pdos_are_counted_and_never_fatal() -> None:
    node = {"name": "wire", "node_id": 1, "profile": "sgh10", "configure": False}
    async with running([node], simulate={"nodes": []}, master={"sync_period_ms": 0}) as gw:
        rt = gw.master.nodes["wire"]
        img = gw.image

        def pos() -> Any:
            return img.nodes["wire"].signals["position"]

        bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            bus.send(frame(0x181, struct.pack("<ih", 1234, 5)))
            await wait_until(lambda: pos().value == 1234, 2, "a good TPDO1")
            # short: 2 bytes for a 6-byte mapping -> ignored, counted
            bus.send(frame(0x181, b"\x01\x02"))
            await wait_until(lambda: rt.image.rx.pdo_too_short == 1, 2, "short PDO counted")
            assert img.counters["decode_errors"] == 1
            assert pos().value == 1234
            # long: 8 bytes -> the mapped 6 bytes are used (CiA 301), counted apart
            bus.send(frame(0x181, struct.pack("<ih", -7, 9) + b"\xff\xff"))
            await wait_until(lambda: pos().value == -7, 2, "long PDO decoded")
            assert rt.image.rx.pdo_too_long == 1
            assert img.counters["pdo_too_long"] == 1
            # a COB-ID nobody configured
            before = img.counters["unknown_cob_id"]
            bus.send(frame(0x3F0, b"\x00"))
            bus.send(frame(0x1A5, b"\x00" * 8))
            await wait_until(lambda: img.counters["unknown_cob_id"] == before + 2, 2, "unknown")
            # still decoding
            bus.send(frame(0x181, struct.pack("<ih", 42, 0)))
            await wait_until(lambda: pos().value == 42, 2, "decoding goes on")
            assert gw.driver.state == "ok"
        finally:
            bus.shutdown()
