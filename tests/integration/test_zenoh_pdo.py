"""``zenoh.publish: pdo``: one Zenoh sample per received TPDO with all its signals, seen by a real
Zenoh subscriber on tcp/127.0.0.1. Against the simulated SGH10 and against frames scripted from
the SGH10 manual (4.3.1.1 Table 5: TPDO1 = position int32, velocity int16) on a virtual bus."""

from __future__ import annotations

import struct
import threading
import time
from typing import Any

import can

from tests.helpers import frame, gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient, drain, sample_where

P = "canopen/test"
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


async def test_one_sample_per_pdo_with_every_signal_its_quality_and_the_record_time() -> None:
    cfg = make_config(
        [WIRE], simulate={"nodes": "all", "motion": {"wire": {"kind": "ramp", "speed": 2000}}},
        zenoh={"publish": "pdo", "batch_ms": 2},  # and the values of 2 ms go out together
    )  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    z = ZClient(cfg.zenoh.listen)
    try:
        assert gw.zenoh is not None and gw.zenoh._sender.batch_s == 0.002  # the publisher's
        pdo = z.subscribe(f"{P}/wire/tpdo/*")
        single = z.subscribe(f"{P}/wire/value/*")
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        first = await sample_where(
            pdo, lambda s: s.body["signals"]["position"]["quality"] == "good", what="a good PDO"
        )
        # SGH10 TPDO1 and TPDO2 carry the same signals: one record, named by TPDO1
        assert first.key == f"{P}/wire/tpdo/1"
        assert set(first.body) == {"ts", "seq", "signals"}
        assert set(first.body["signals"]) == {"position", "velocity"}
        pos = first.body["signals"]["position"]
        assert set(pos) == {"value", "unit", "quality"} and pos["unit"] == "mm"
        assert abs(first.body["ts"] - time.time()) < 5.0  # source time of the CAN frame
        assert first.timestamp is not None  # a zenoh timestamp on every sample
        second = await sample_where(pdo, lambda s: True, what="the next PDO")
        assert second.body["seq"] > first.body["seq"]  # newer frames only, in order
        assert second.body["signals"]["position"]["value"] != pos["value"]  # the ramp moves
        assert drain(single) == []  # the values go out in the PDO's sample, not one by one
        # a get of one signal still answers from the image
        r = await z.get_one(f"{P}/wire/value/position")
        assert r.ok and r.body["quality"] == "good" and r.body["seq"] >= second.body["seq"]
        assert gw.zenoh is not None and gw.zenoh.publications >= 2
    finally:
        z.close()
        await gw.stop()


async def test_scripted_frames_each_new_frame_a_sample_and_a_lost_node_goes_stale() -> None:
    """Frames written from the manual (no simulator): boot-up, heartbeats, TPDO1. A signal with
    its own ``publish: every`` goes out on its value key, not in the PDO's sample; a node that stops its heartbeat gets
    its last PDO republished as stale, same seq (quality travels with each value)."""
    node = {"name": "wire", "node_id": 1, "profile": "sgh10", "configure": False,
            "identity_check": False,  # scripted frames: no SDO server to read 1018h from
            "supervision": "heartbeat", "heartbeat_ms": 100,
            "signals": {"velocity": {"publish": "every"}}}  # fmt: skip
    cfg = make_config([node], simulate={"nodes": []}, master={"sync_period_ms": 0},
                      zenoh={"publish": "pdo"})  # fmt: skip
    gw = gateway_of(cfg)
    await gw.start()
    z = ZClient(cfg.zenoh.listen)
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    beating = threading.Event()
    silent = threading.Event()  # ends the device's wait at once when it goes silent

    def device_heartbeat() -> None:  # the device's own 50 ms heartbeat, until it goes silent
        while beating.is_set():
            bus.send(frame(0x701, "05"))
            silent.wait(0.05)  # the device's heartbeat period

    try:
        pdo = z.subscribe(f"{P}/wire/tpdo/*")
        velocity = z.subscribe(f"{P}/wire/value/velocity")
        img = gw.image.nodes["wire"]
        bus.send(frame(0x701, "00"))  # boot-up
        beating.set()
        threading.Thread(target=device_heartbeat, daemon=True).start()
        await wait_until(img.operational, 8, "operational from the scripted heartbeat")
        got: list[dict[str, Any]] = []
        for position in (1000, 1000, -25):  # the same values twice: each frame is a sample
            bus.send(frame(0x181, struct.pack("<ih", position, 7)))
            s = await sample_where(
                pdo, lambda s, p=position: s.body["signals"]["position"]["value"] == p * 0.1
                and s.body["seq"] > (got[-1]["seq"] if got else 0), what=f"position {position}",
            )  # fmt: skip
            got.append(s.body)
        assert [g["seq"] for g in got] == sorted({g["seq"] for g in got})
        assert all(set(g["signals"]) == {"position"} for g in got)  # velocity: its own key
        v = await sample_where(velocity, lambda s: s.body["seq"] == got[-1]["seq"], what="velocity")
        assert gw.zenoh is not None
        sc = gw.zenoh.pubs[("wire", "velocity")].scaling
        assert v.body["value"] == 7 * sc.scale + sc.offset and v.body["quality"] == "good"
        assert got[-1]["signals"]["position"]["quality"] == "good"
        beating.clear()
        silent.set()  # the node goes silent: lost after its heartbeat timeout
        stale = await sample_where(
            pdo, lambda s: s.body["signals"]["position"]["quality"] == "stale", what="stale PDO"
        )
        assert stale.body["seq"] == got[-1]["seq"]  # the same frame, its quality changed
        assert stale.body["signals"]["position"]["value"] == got[-1]["signals"]["position"]["value"]
    finally:
        beating.clear()
        silent.set()
        bus.shutdown()
        z.close()
        await gw.stop()
