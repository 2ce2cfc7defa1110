"""The Zenoh bridge peer to peer: a real Zenoh session on tcp/127.0.0.1 talks to a gateway whose
devices are simulated on a private virtual CAN bus. Values, liveliness, events, queries (SDO,
set points, NMT, snapshot, catalogue) and errors, as a cloud client sees them."""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import can

from canopen_gateway.app import Gateway
from tests.helpers import gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient, drain, next_sample, sample_where

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}
RAMP = {"wire": {"kind": "ramp", "speed": 2000}}
HOLD = {"wire": {"kind": "hold"}}
P = "canopen/test"


@asynccontextmanager
async def running(
    nodes: list[dict[str, Any]], motion: dict[str, Any] | None = None, **sections: Any
) -> AsyncIterator[tuple[Gateway, ZClient]]:
    """A started gateway (every node simulated) and a Zenoh peer connected to it; Zenoh writes
    are on unless ``zenoh={"writes": False}`` is given."""
    sections["zenoh"] = {"writes": True, **sections.get("zenoh", {})}
    cfg = make_config(nodes, simulate={"nodes": "all", "motion": motion or RAMP}, **sections)
    gw = gateway_of(cfg)
    await gw.start()
    client = ZClient(cfg.zenoh.listen)
    try:
        yield gw, client
    finally:
        client.close()
        await gw.stop()


async def operational(gw: Gateway, *names: str) -> None:
    for name in names:
        await wait_until(lambda n=name: gw.image.nodes[n].operational(), 8, f"{name} operational")


def sim_value(gw: Gateway, node: str, index: int, sub: int) -> Any:
    assert gw.sim is not None
    return gw.sim.runner.call(lambda now: gw.sim.nodes[node].get(index, sub))


# --------------------------------------------------------------------------- values


async def test_value_samples_are_json_with_value_unit_source_time_quality_seq_and_zenoh_timestamp() -> (
    None
):
    async with running([WIRE]) as (gw, z):
        q = z.subscribe(f"{P}/wire/value/position")
        await operational(gw, "wire")
        first = await sample_where(q, lambda s: s.body["quality"] == "good", what="a good sample")
        assert set(first.body) == {"value", "unit", "ts", "quality", "seq"}
        assert first.body["unit"] == "mm"
        assert isinstance(first.body["value"], (int, float))
        assert abs(first.body["ts"] - time.time()) < 5.0  # source time of the CAN frame
        assert first.timestamp is not None  # zenoh timestamp on every sample
        second = await sample_where(q, lambda s: s.body["quality"] == "good", what="next sample")
        assert second.body["seq"] > first.body["seq"]
        assert second.body["value"] != first.body["value"]  # ramp: report by exception
        assert (
            second.timestamp is not None
            and second.timestamp.get_time() >= first.timestamp.get_time()
        )


async def test_a_value_that_does_not_change_is_published_once_not_per_frame() -> None:
    async with running([WIRE], HOLD) as (gw, z):
        await operational(gw, "wire")
        q = z.subscribe(f"{P}/wire/value/position")
        seq0 = gw.image.nodes["wire"].signals["position"].seq
        await wait_until(lambda: gw.image.nodes["wire"].signals["position"].seq >= seq0 + 10, 5, "10 more position frames")
        samples = drain(q)
        assert samples == [], "an unchanged value was republished"
        # a zenoh get still answers the current value
        r = await z.get_one(f"{P}/wire/value/position")
        assert r.ok and r.body["quality"] == "good" and r.body["seq"] >= seq0 + 10


async def test_publish_every_sends_each_frame_and_max_rate_caps_the_rate() -> None:
    """The rate cap is judged on the bridge's clock, a fake one here: while it stands still a
    4 Hz signal is held back however many frames come; 0.25 s later its latest value goes out
    once."""
    async with running(
        [{**WIRE, "signals": {"velocity": {"max_rate_hz": 4}}}],
        HOLD,
        zenoh={"publish": "every"},
    ) as (gw, z):
        await operational(gw, "wire")
        bridge = gw.zenoh
        assert bridge is not None
        pos = z.subscribe(f"{P}/wire/value/position")
        vel = z.subscribe(f"{P}/wire/value/velocity")
        await sample_where(pos, lambda s: s.body["quality"] == "good", what="a position sample")
        await sample_where(vel, lambda s: s.body["quality"] == "good", what="a velocity sample")
        now = [time.monotonic()]
        bridge.clock = lambda: now[0]  # the bridge's clock stands still from here
        position = gw.image.nodes["wire"].signals
        vpolicy = bridge.pubs[("wire", "velocity")].policy
        seq = position["position"].seq
        await wait_until(lambda: position["position"].seq > seq, 5, "a frame on the still clock")
        published = vpolicy.published_count
        seq0 = position["position"].seq
        await wait_until(lambda: position["position"].seq >= seq0 + 20, 5, "20 more frames")
        got: list[int] = []  # the position samples up to frame 20, as they arrive
        while not got or got[-1] < seq0 + 20:
            got.append((await next_sample(pos, what="frame 20")).body["seq"])
        assert vpolicy.published_count == published, "max_rate_hz 4 exceeded on a still clock"
        assert vpolicy.pending  # the latest velocity waits for its turn
        now[0] += 0.25  # one period of 4 Hz later: the held-back value goes out, once
        await wait_until(lambda: vpolicy.published_count == published + 1, 5, "held-back sample")
        assert (await sample_where(vel, lambda s: True, what="the held-back velocity")).body
        seq1 = position["position"].seq
        await wait_until(lambda: position["position"].seq >= seq1 + 10, 5, "10 more frames")
        assert vpolicy.published_count == published + 1
        # publish: every: each frame of the position went out, in order
        every = [s.body["seq"] for s in drain(pos)]
        assert got == sorted(got) and every == sorted(every)
        assert len([q for q in got if q > seq0]) >= 18, f"publish: every sends each frame: {got}"


async def test_a_lost_node_republishes_its_values_as_stale_and_good_again_when_back() -> None:
    async with running([WIRE], HOLD) as (gw, z):
        await operational(gw, "wire")
        q = z.subscribe(f"{P}/wire/value/position")
        state = z.subscribe(f"{P}/wire/state")
        gw.sim.runner.call(lambda now: gw.sim.nodes["wire"].silence())
        stale = await sample_where(q, lambda s: s.body["quality"] == "stale", what="stale position")
        lost = await sample_where(
            state, lambda s: s.body["alive"] is False, what="state alive false"
        )
        assert lost.body["loss_count"] >= 1 and lost.body["operational"] is False
        gw.sim.runner.call(lambda now: gw.sim.nodes["wire"].unsilence(now))
        good = await sample_where(q, lambda s: s.body["quality"] == "good", what="good again")
        assert good.body["value"] == stale.body["value"]  # hold: same value, quality changed
        await sample_where(state, lambda s: s.body["alive"] is True, what="state alive again")


# --------------------------------------------------------------------------- liveliness


async def test_node_token_goes_away_when_the_node_is_silenced_and_comes_back() -> None:
    async with running([WIRE, DISPLAY]) as (gw, z):
        await operational(gw, "wire", "display")
        tokens = z.watch_liveliness(f"{P}/alive/**")
        # the display's token comes once its guarding-bit link is OK (first echo): wait for both
        seen: set[str] = set()
        await sample_where(
            tokens,
            lambda s: s.kind == "PUT"
            and (seen.add(s.key) or {f"{P}/alive/wire", f"{P}/alive/display"} <= seen),
            what="wire and display tokens",
        )
        assert await z.alive_tokens(f"{P}/alive/**") == {
            f"{P}/alive/_gateway",
            f"{P}/alive/wire",
            f"{P}/alive/display",
        }
        gw.sim.runner.call(lambda now: gw.sim.nodes["wire"].silence())
        gone = await sample_where(
            tokens, lambda s: s.key == f"{P}/alive/wire", what="wire token gone"
        )
        assert gone.kind == "DELETE"
        assert f"{P}/alive/wire" not in await z.alive_tokens(f"{P}/alive/**")
        gw.sim.runner.call(lambda now: gw.sim.nodes["wire"].unsilence(now))
        back = await sample_where(
            tokens, lambda s: s.key == f"{P}/alive/wire", what="wire token back"
        )
        assert back.kind == "PUT"


async def test_ap05_token_goes_away_while_its_guarding_bit_link_is_in_fault() -> None:
    display = {
        **DISPLAY,
        "guarding_bit": {"tolerance_missed": 3, "tolerance_ms": 300},
        "external_heartbeat": {"interval_ms": 200, "source": "rpdo", "keepalive_ms": 50},
    }
    async with running([display]) as (gw, z):
        await operational(gw, "display")
        tokens = z.watch_liveliness(f"{P}/alive/display")
        state = z.subscribe(f"{P}/display/state")
        await sample_where(tokens, lambda s: s.kind == "PUT", what="display token")
        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].freeze_guarding_echo(True, now))
        assert (await next_sample(tokens, what="token gone")).kind == "DELETE"
        fault = await sample_where(state, lambda s: s.body["link"] == "fault", what="link fault")
        assert fault.body["alive"] is True  # heartbeat still fine: only the link is down
        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].freeze_guarding_echo(False, now))
        assert (await next_sample(tokens, what="token back")).kind == "PUT"


# --------------------------------------------------------------------------- queries


async def test_sdo_upload_download_and_abort_through_queries() -> None:
    async with running([WIRE], zenoh={"reads": "all"}) as (gw, z):  # any object: 7777h too
        await operational(gw, "wire")
        name = await z.get_one(f"{P}/wire/sdo/1008/00")
        assert name.ok and name.body == {"node": "wire", "object": "0x1008:00", "value": "SGH10"}

        w = await z.get_one(f"{P}/wire/sdo/0x6000/0", payload="5")  # 0x prefix and short sub ok
        assert w.ok and w.body["ok"] is True and w.body["object"] == "0x6000:00"
        assert sim_value(gw, "wire", 0x6000, 0) == 5
        r = await z.get_one(f"{P}/wire/sdo/6000/00")
        assert r.ok and r.body["value"] == 5
        typed = await z.get_one(f"{P}/wire/sdo/6000/00", payload='{"value": 4, "type": "uint16"}')
        assert typed.ok and sim_value(gw, "wire", 0x6000, 0) == 4

        ro = await z.get_one(f"{P}/wire/sdo/1000/00", payload="5")
        assert not ro.ok
        assert ro.body["error"] == "sdo_abort"
        assert ro.body["code"] == "0x06010002"  # DS-301: attempt to write a read only object
        assert "read only" in ro.body["text"]
        missing = await z.get_one(f"{P}/wire/sdo/7777/00")
        assert not missing.ok and missing.body["code"] == "0x06020000"
        assert "does not exist" in missing.body["text"]


async def test_a_set_point_written_through_zenoh_reaches_the_simulated_ap05() -> None:
    async with running([DISPLAY]) as (gw, z):
        await operational(gw, "display")
        ack = await z.get_one(f"{P}/display/set/set_point2", payload="4321")
        assert ack.ok, ack.body
        assert ack.body == {
            "ok": True, "node": "display", "signal": "set_point2", "value": 4321, "raw": 4321,
            "via": "rpdo",
        }  # fmt: skip
        # the ack came after the RPDO was sent; the device has it in 5F16h:01 (AP05 manual 5F16h)
        await wait_until(lambda: sim_value(gw, "display", 0x5F16, 1) == 4321, 3, "5F16h:01")

        bits = await z.get_one(
            f"{P}/display/set/control_word", payload='{"bits": {"set_point2_valid": true}}'
        )
        assert bits.ok, bits.body
        # AP05 manual 5.3.2 table 27: control word bit 9 = validity of set point2
        await wait_until(lambda: sim_value(gw, "display", 0x5F0C, 0) & (1 << 9), 3, "control bit 9")

        many = await z.get_one(f"{P}/display/set", payload='{"set_point2": -77, "set_point1": 12}')
        assert many.ok and many.body["written"] == {"set_point2": -77, "set_point1": 12}
        # 5F16h is UNSIGNED32 in the device (EDS): -77 arrives as its two's complement
        await wait_until(
            lambda: sim_value(gw, "display", 0x5F16, 1) == -77 & 0xFFFFFFFF, 3, "5F16h:01 = -77"
        )
        await wait_until(lambda: sim_value(gw, "display", 0x5F16, 3) == 12, 3, "5F16h:03 = 12")

        snap = await z.get_one(f"{P}/display/snapshot")
        assert snap.ok and snap.body["values"]["set_point2"]["value"] == -77


async def test_an_engineering_value_written_is_scaled_back_to_the_raw_value() -> None:
    async with running(
        [{**WIRE, "signals": {"calibration_value": {"scale": 0.1, "unit": "mm"}}}]
    ) as (gw, z):
        await operational(gw, "wire")
        ack = await z.get_one(f"{P}/wire/set/calibration_value", payload="12.3")
        assert ack.ok, ack.body
        assert ack.body["raw"] == 123 and ack.body["via"] == "sdo"
        obj = gw.master.nodes["wire"].lp.profile.signal("calibration_value").object
        assert sim_value(gw, "wire", obj.index, obj.sub) == 123
        back = await z.get_one(f"{P}/wire/value/calibration_value")
        assert back.ok and back.body["value"] == 12.3 and back.body["unit"] == "mm"
        # docs/zenoh.md "Value": a word with named bits adds "bits", also when read by SDO
        word = await z.get_one(f"{P}/wire/value/operating_parameters")
        assert word.ok and word.body["source"] == "sdo" and word.body["value"] == 0x0004
        assert word.body["bits"]["scaling_enabled"] is True
        assert word.body["bits"]["counting_direction_descending"] is False


async def test_malformed_payloads_and_unknown_keys_get_reply_err_saying_what_was_expected() -> None:
    cases = [
        # (selector, payload, error kind, words of the message)
        (f"{P}/nothing", None, "bad_request", "expected canopen/test/catalog"),
        (f"{P}/ghost/snapshot", None, "node_unknown", "configured nodes: display, wire"),
        (f"{P}/wire/sdo/xyz/00", None, "bad_request", "not hexadecimal"),
        (f"{P}/wire/sdo/6000", None, "bad_request", "sdo/<index hex>/<sub hex>"),
        (f"{P}/wire/sdo/6000/00", "{oops", "bad_request", "not JSON"),
        (f"{P}/wire/sdo/6000/00", '{"hex": "zz"}', "bad_request", "not hexadecimal"),
        (f"{P}/display/set/set_point2", None, "bad_request", "payload missing"),
        (f"{P}/display/set/set_point2", "abc", "bad_request", '{"value": v}'),
        (f"{P}/display/set/set_point2", "[1, 2]", "bad_request", "expected a JSON value"),
        (f"{P}/display/set/set_point2", "1.5", "value_out_of_range", "an integer"),
        (f"{P}/display/set/set_point2", "4294967296", "value_out_of_range", "int32"),
        (f"{P}/display/set/nosuch", "1", "unmapped", "no signal 'nosuch'"),
        (f"{P}/wire/set/position", "1", "read_only", "read-only"),
        (f"{P}/display/set/control_word", '{"bits": {"nosuch": true}}', "bad_request", "no bit"),
        (
            f"{P}/display/set/control_word",
            '{"bits": {"reserved_bit0": true}}',
            "bad_request",
            "not writable",
        ),
        (f"{P}/display/set", '"x"', "bad_request", '{"signal": value'),
        (f"{P}/wire/nmt", None, "bad_request", "start, stop, preop"),
        (f"{P}/wire/nmt", "jump", "bad_request", "unknown NMT command 'jump'"),
        (f"{P}/alive/wire", None, "bad_request", "liveliness"),
        (f"{P}/wire/emcy", None, "bad_request", "subscribe"),
    ]
    async with running([WIRE, DISPLAY]) as (gw, z):
        await operational(gw, "wire", "display")
        for selector, payload, kind, words in cases:
            r = await z.get_one(selector, payload=payload)
            assert not r.ok, f"{selector} {payload!r} should fail, got {r.body}"
            assert r.body["error"] == kind, (selector, payload, r.body)
            assert words in r.body["message"], (selector, payload, r.body["message"])
            assert r.body["key"] == selector
        # an SDO type no value can have: refused before anything is sent to the device
        r = await z.get_one(f"{P}/wire/sdo/1018/01?type=foo")
        assert not r.ok and r.body["error"] == "bad_request"
        assert r.body["message"].startswith("type 'foo' is not one of bool, int8,"), r.body
        # nothing crashed: the gateway still answers and publishes
        ok = await z.get_one(f"{P}/wire/state")
        assert ok.ok and ok.body["alive"] is True


async def test_a_write_to_a_node_that_is_not_operational_is_refused_with_the_reason() -> None:
    async with running([DISPLAY]) as (gw, z):
        await operational(gw, "display")
        gw.sim.runner.call(lambda now: gw.sim.nodes["display"].silence())
        await wait_until(lambda: not gw.image.nodes["display"].health.alive, 5, "display lost")
        r = await z.get_one(f"{P}/display/set/set_point2", payload="1")
        assert not r.ok and r.body["error"] == "node_not_operational"
        assert "not alive" in r.body["message"]


async def test_snapshot_state_catalog_and_wildcard_gets() -> None:
    async with running([WIRE, DISPLAY]) as (gw, z):
        await operational(gw, "wire", "display")
        await wait_until(lambda: gw.image.nodes["wire"].signals["position"].seq > 0, 3, "position")

        snap = await z.get_one(f"{P}/wire/snapshot")
        assert snap.ok and snap.body["node"] == "wire"
        assert snap.body["state"]["nmt_state"] == "operational"
        assert snap.body["values"]["position"]["unit"] == "mm"
        assert snap.body["values"]["position"]["quality"] == "good"

        cat = (await z.get_one(f"{P}/catalog")).body
        assert cat["gateway"] == "test" and cat["prefix"] == P
        pos = cat["nodes"]["wire"]["signals"]["position"]
        assert pos["type"] == "int32" and pos["unit"] == "mm" and pos["object"] == "0x6020:01"
        assert pos["modbus"] and {"unit_id", "table", "address"} <= set(pos["modbus"][0])
        assert pos["zenoh"] == {"value": f"{P}/wire/value/position"}
        assert (
            cat["nodes"]["display"]["signals"]["set_point2"]["zenoh"]["set"]
            == f"{P}/display/set/set_point2"
        )
        assert cat["nodes"]["wire"]["keys"]["state"] == f"{P}/wire/state"
        # the AP05 text rows (one string per row) are signals of the catalogue like the others
        row1 = cat["nodes"]["display"]["signals"]["set_point1_text"]
        assert (row1["type"], row1["access"], row1["transport"]) == ("string", "rw", "pdo")
        assert row1["modbus"] and row1["modbus"][0]["table"] == "hr"
        assert row1["zenoh"]["set"] == f"{P}/display/set/set_point1_text"

        states = await z.get(f"{P}/*/state")
        assert sorted(r.key for r in states) == [f"{P}/display/state", f"{P}/wire/state"]
        assert all(r.ok and r.body["operational"] for r in states)

        everything = await z.get(f"{P}/**")
        keys = {r.key for r in everything}
        assert all(r.ok for r in everything)
        assert {f"{P}/catalog", f"{P}/wire/snapshot", f"{P}/wire/value/position"} <= keys
        assert not any("/sdo/" in k or "/set" in k or k.endswith("/nmt") for k in keys)


async def test_nmt_stop_and_start_through_zenoh_show_in_state_events() -> None:
    async with running([WIRE]) as (gw, z):
        await operational(gw, "wire")
        state = z.subscribe(f"{P}/wire/state")
        ack = await z.get_one(f"{P}/wire/nmt", payload="stop")
        assert ack.ok and ack.body == {"ok": True, "node": "wire", "nmt": "stop"}
        stopped = await sample_where(
            state, lambda s: s.body["nmt_state"] == "stopped", what="stopped"
        )
        assert stopped.body["operational"] is False
        ack = await z.get_one(f"{P}/wire/nmt", payload='{"command": "start"}')
        assert ack.ok
        await sample_where(
            state, lambda s: s.body["nmt_state"] == "operational", what="operational"
        )


async def test_raw_pdo_bytes_are_published_for_received_and_sent_pdos() -> None:
    async with running([WIRE, DISPLAY], zenoh={"raw_pdo": True}) as (gw, z):
        await operational(gw, "wire", "display")
        raw = z.subscribe(f"{P}/*/pdo/*")
        tpdo1 = await sample_where(raw, lambda s: s.key == f"{P}/wire/pdo/181", what="wire TPDO1")
        assert isinstance(tpdo1.body, bytes) and len(tpdo1.body) == 6  # SGH10: position + velocity
        assert tpdo1.timestamp is not None
        await z.get_one(f"{P}/display/set/set_point2", payload="300")
        # AP05 manual 5.3.1.3: RPDO2 (0x300 + node id: 0x37D) carries set point2 in bytes 0-3
        rpdo2 = await sample_where(
            raw,
            lambda s: s.key == f"{P}/display/pdo/37d" and s.body[:4] == struct.pack("<i", 300),
            what="display RPDO2 with 300",
        )
        assert len(rpdo2.body) == 8


async def test_emcy_events_all_arrive_under_load() -> None:
    """Raise and clear an error 150 times in the simulated SGH10 while a flood of TPDOs keeps
    the reader thread and the value publishers busy: all 300 EMCY events arrive, in order."""
    rounds = 150
    async with running([WIRE], zenoh={"publish": "every"}) as (gw, z):
        await operational(gw, "wire")
        events = z.subscribe(f"{P}/wire/emcy")
        values = z.subscribe(f"{P}/wire/value/*")
        stop = threading.Event()

        def flood() -> None:
            bus = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
            try:
                i = 0
                while not stop.is_set() and i < 20000:
                    data = struct.pack("<ih", i, 7)
                    bus.send(can.Message(arbitration_id=0x181, data=data, is_extended_id=False))
                    i += 1
                    if i % 500 == 0:
                        time.sleep(0.005)  # let the reader breathe; still ~50k frames/s offered
            finally:
                bus.shutdown()

        flooder = threading.Thread(target=flood, daemon=True)
        flooder.start()
        sim = gw.sim.nodes["wire"]
        count0 = gw.image.nodes["wire"].health.emcy_count

        def burst(now: float) -> None:
            for _ in range(rounds):
                sim.raise_emcy(0xFF05, 0x80, now=now)  # SGH10 manual 4.5.1: manufacturer error
                sim.clear_emcy(0xFF05, now=now)

        gw.sim.runner.call(burst)
        got = []
        while len(got) < 2 * rounds:
            got.append((await next_sample(events, 10, f"EMCY {len(got) + 1}")).body)
        stop.set()
        flooder.join(5)
        codes = [e["code"] for e in got]
        assert codes == ["0xFF05", "0x0000"] * rounds
        assert [e["count"] for e in got] == list(range(count0 + 1, count0 + 2 * rounds + 1))
        assert got[0]["reset"] is False and got[1]["reset"] is True
        assert got[0]["register"] & 0x80 and got[1]["register"] == 0
        assert len(drain(values)) > 0  # the values were flowing meanwhile
