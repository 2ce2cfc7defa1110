"""A hot-standby pair seen from the north: two in-process gateways of one config on one virtual
bus (a simulated SGH10 whose position ramps, an AP05), each with its Modbus server (a pymodbus
client over TCP) and its Zenoh session (real sessions through a router-mode session on
loopback, a cloud client beside them).

The standby serves reads from its image and refuses every write (Modbus 0x06, Zenoh
``not_active``); only the active one publishes, and after a take-over the cloud sees one
gateway: the active token moves, no sample twice, ``seq`` never goes back.
"""

from __future__ import annotations

import asyncio
import queue
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.config import parse_config
from canopen_gateway.modbus.watchdog import WatchdogState
from tests.helpers import (
    free_port,
    gateway_of,
    make_config,
    node_operational,
    simulated_bus,
    wait_until,
)
from tests.integration.test_pair import Sent, position_good
from tests.zenoh_client import Sample, ZClient, drain, next_sample, open_router, sample_where

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
DISPLAY = {"name": "display", "node_id": 125, "profile": "ap05"}
RAMP = {"wire": {"kind": "ramp", "speed": 2000}}
LOGICAL, HB_MS = 100, 200
P = "canopen/test"
POSITION = f"{P}/wire/value/position"
GATEWAY_UNIT, PAIR_ROLE = 247, 21  # docs/modbus.md: the gateway unit's role register
CONTROL_WORD, NMT_REGISTER, CONTROL_COIL = 106, 0, 100  # AP05 unit 125 (docs/modbus.md)
BUSY = 0x06  # Modbus Application Protocol V1.1b3, 7: server device busy


def pair_configs(router: str) -> tuple[Any, Any]:
    base = make_config(
        [WIRE, DISPLAY],
        master={"node_id": LOGICAL, "heartbeat_ms": HB_MS, "sync_period_ms": 0},
        modbus={"watchdog_ms": 500},
        # peers that listen: two peers of one router that cannot reach each other directly
        # do not get each other's samples (the router does not relay between peers)
        zenoh={"mode": "peer", "connect": [router], "writes": True},
        health={"port": free_port()},
        simulate={"nodes": "all", "motion": RAMP},
    )
    raw = base.model_dump(exclude_none=True)
    red = {"priority_slot_ms": 50, "device_slot_ms": 1}
    a = {**raw, "master": {**raw["master"], "redundancy": {
        **red, "node_id": 101, "priority": 0, "peer_node_id": 102}}}  # fmt: skip
    b = {
        **raw,
        "master": {**raw["master"], "redundancy": {
            **red, "node_id": 102, "priority": 1, "peer_node_id": 101}},
        "modbus": {**raw["modbus"], "port": free_port()},
        "zenoh": {**raw["zenoh"], "listen": [f"tcp/127.0.0.1:{free_port()}"]},
        "health": {**raw["health"], "port": free_port()},
    }  # fmt: skip
    return parse_config(a, environ={}), parse_config(b, environ={})


class Pair:
    def __init__(self, a: Gateway, b: Gateway, sent_a: Sent, z: ZClient, router: str):
        self.a, self.b, self.sent_a, self.z, self.router = a, b, sent_a, z, router

    async def kill_a(self) -> None:
        """A dies: not one more frame on the bus, its Zenoh session closes."""
        self.sent_a.silent = True
        self.a.master.mastering = False
        assert self.a.zenoh is not None
        await self.a.zenoh.stop()


@asynccontextmanager
async def pair_running(a_ahead_frames: int = 0) -> AsyncIterator[Pair]:
    """A and B running, B standby; B starts when A has counted ``a_ahead_frames`` positions
    (A's frame counter then stays that far ahead of B's)."""
    router_endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router(router_endpoint)
    cfg_a, cfg_b = pair_configs(router_endpoint)
    sim = simulated_bus(cfg_a, names=["wire", "display"])
    a, b = gateway_of(cfg_a, simulate=False), gateway_of(cfg_b, simulate=False)
    sent_a = Sent(a)
    z = ZClient([router_endpoint], mode="client")
    try:
        await a.start()
        # the devices power on once A listens: their boot-ups are the first frames it hears (on a
        # bus silent from its start a first master waits 2 s before it claims the bus)
        sim.start()
        for name in ("wire", "display"):
            await wait_until(lambda n=name: node_operational(a, n), 10, f"A configures {name}")
        position = a.image.nodes["wire"].signals
        await wait_until(lambda: position["position"].seq >= a_ahead_frames, 20, "A ahead")
        await b.start()  # the duplicate-prefix check lets the partner in
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        await wait_until(lambda: position_good(b), 5, "B serves the position good")
        yield Pair(a, b, sent_a, z, router_endpoint)
    finally:
        z.close()
        await b.stop()
        await a.stop()
        sim.stop()
        router.close()


@asynccontextmanager
async def modbus_client(gw: Gateway) -> AsyncIterator[AsyncModbusTcpClient]:
    assert gw.modbus is not None
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
    try:
        await client.connect()
        yield client
    finally:
        client.close()


async def role_register(client: AsyncModbusTcpClient) -> int:
    rr = await client.read_input_registers(PAIR_ROLE, count=1, device_id=GATEWAY_UNIT)
    assert not rr.isError(), rr
    return int(rr.registers[0])


async def poll_role(client: AsyncModbusTcpClient) -> None:
    """A PLC's cycle: the role register every 100 ms, until cancelled."""
    while True:
        await client.read_input_registers(PAIR_ROLE, count=1, device_id=GATEWAY_UNIT)
        await asyncio.sleep(0.1)


async def every_write_answers(client: AsyncModbusTcpClient) -> set[int]:
    """The exception code of each write function (05, 06, 15, 16, 22, 23, the NMT register)."""
    answers = [
        await client.write_coil(CONTROL_COIL + 2, True, device_id=125),
        await client.write_register(CONTROL_WORD, 0x0004, device_id=125),
        await client.write_coils(CONTROL_COIL + 2, [True], device_id=125),
        await client.write_registers(CONTROL_WORD, [0x0004], device_id=125),
        await client.mask_write_register(
            address=CONTROL_WORD, and_mask=0xFFFB, or_mask=0x0004, device_id=125
        ),
        await client.readwrite_registers(
            read_address=CONTROL_WORD, read_count=1, write_address=CONTROL_WORD,
            values=[0x0004], device_id=125,
        ),  # fmt: skip
        await client.write_register(NMT_REGISTER, 1, device_id=125),
    ]
    assert all(r.isError() for r in answers), answers
    return {r.exception_code for r in answers}


async def test_the_standby_serves_reads_refuses_writes_0x06_and_takes_writes_once_active(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with pair_running() as pair:
        a, b = pair.a, pair.b
        async with modbus_client(a) as client_a, modbus_client(b) as client_b:
            assert await role_register(client_a) == 1
            assert await role_register(client_b) == 2
            # reads are served from the standby's image
            position = next(
                p for p in b.modbus.regmap.points if (p.node, p.name) == ("wire", "position")
            )
            rr = await client_b.read_input_registers(position.address, count=2, device_id=1)
            assert not rr.isError(), rr
            # a configuration object is read by SDO: that needs the bus, busy on the standby
            limit = next(
                p
                for p in b.modbus.regmap.points
                if (p.node, p.name) == ("wire", "work_area_1_low_limit")
            )
            rr = await client_b.read_holding_registers(limit.address, count=2, device_id=1)
            assert rr.isError() and rr.exception_code == BUSY, rr
            rr = await client_a.read_holding_registers(limit.address, count=2, device_id=1)
            assert not rr.isError(), rr
            # identification from the EDS / profile, quietly (no SDO on the standby)
            ident = await client_b.read_device_information(read_code=1, device_id=125)
            assert not ident.isError() and ident.information, ident
            assert "identification of display" not in caplog.text
            # every write function is refused "server device busy", nothing reaches the bus
            frames_before = b.image.counters["frames_out"]
            assert await every_write_answers(client_b) == {BUSY}
            assert b.image.counters["frames_out"] == frames_before
            assert b.modbus.store.exceptions.get(BUSY) == 8
            # a PLC polling the standby arms no output watchdog: no timer, nothing to trip
            assert b.modbus.watchdog.state is WatchdogState.STANDBY
            assert b.modbus.watchdog.next_deadline() is None
            assert a.modbus.watchdog.state is WatchdogState.ARMED

            # the PLC polls both members through the take-over (docs/redundancy.md)
            polling = asyncio.create_task(poll_role(client_b))
            await pair.kill_a()
            await wait_until(lambda: b.master.role == "active", 5, "B takes over")
            # its watchdog counts from the PLC's last request to it, refused or not
            assert b.modbus.watchdog.state is WatchdogState.ARMED
            polling.cancel()
            assert await role_register(client_b) == 1
            rr = await client_b.write_register(CONTROL_WORD, 0x0004, device_id=125)
            assert not rr.isError(), rr
            assert sum(b.modbus.watchdog.trips.values()) == 0


async def test_healthz_and_metrics_say_the_role_and_the_peer() -> None:
    async with pair_running() as pair:
        a, b = pair.a, pair.b
        await wait_until(lambda: b.status()["peer"]["role"] == "active", 5, "B hears A active")
        doc = b.status()
        assert doc["role"] == "standby"
        assert doc["peer"]["node_id"] == 101 and doc["peer"]["priority"] == 0
        await wait_until(lambda: a.status()["peer"]["role"] == "standby", 5, "A hears B")
        assert a.status()["role"] == "active" and a.status()["peer"]["heartbeat_age_s"] is not None
        assert b.overview()["pair"]["role"] == "standby"
        metrics = b.metrics.render().decode()
        assert "canopen_gateway_pair_role 2.0" in metrics
        await pair.kill_a()
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        await wait_until(lambda: b.status()["peer"]["heard"] is False, 5, "A is gone")
        metrics = b.metrics.render().decode()
        assert "canopen_gateway_pair_role 1.0" in metrics
        assert "canopen_gateway_pair_takeovers_total 1.0" in metrics


def _seqs(samples: list[Sample]) -> list[int]:
    return [int(s.body["seq"]) for s in samples]


async def test_the_cloud_sees_one_gateway_across_a_take_over() -> None:
    # A's frame counter far ahead of B's: B's own numbers would go back at the take-over
    async with pair_running(a_ahead_frames=600) as pair:
        a, b, z = pair.a, pair.b, pair.z
        assert a.zenoh is not None and b.zenoh is not None
        active = z.watch_liveliness(f"{P}/alive/_active/**")
        values = z.subscribe(POSITION)
        states: queue.Queue[Sample] = z.subscribe(f"{P}/*/state")
        first = await sample_where(values, lambda s: s.body["quality"] == "good", 8, "a value")
        tok = await sample_where(active, lambda s: s.kind == "PUT", 5, "the active token")
        assert tok.key == f"{P}/alive/_active/101"
        members = await z.alive_tokens(f"{P}/alive/_pair/**")
        assert members == {f"{P}/alive/_pair/{LOGICAL}/101", f"{P}/alive/_pair/{LOGICAL}/102"}
        await wait_until(lambda: b.zenoh.heard.get(POSITION) > 0, 5, "B hears A's values")
        # only A publishes: B put nothing, and every sample is A's
        assert b.zenoh.publications == 0 and b.zenoh.events_sent == 0
        a_zid = str(a.zenoh.session.zid())
        before = [first, *drain(values)]
        assert {str(s.timestamp.get_id()) for s in before} == {a_zid}
        # both answer gets from their image, B with the numbers the cloud saw (never lower)
        heard = b.zenoh.heard.get(POSITION)
        assert (await b.zenoh.dispatch(POSITION, None))["seq"] >= heard
        # a get on the pair: one reply per key (the latest, consolidated)
        replies = await z.get(POSITION)
        assert len(replies) == 1 and replies[0].ok, replies
        # a write to the pair: A does it, B answers not_active
        replies = await z.get(f"{P}/display/nmt", payload="start")
        assert sorted((r.ok, r.body.get("error")) for r in replies) == [
            (False, "not_active"),
            (True, None),
        ], replies

        await pair.kill_a()
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        gone = await sample_where(active, lambda s: s.kind == "DELETE", 5, "A's token gone")
        assert gone.key == f"{P}/alive/_active/101"
        tok = await sample_where(active, lambda s: s.kind == "PUT", 5, "B's active token")
        assert tok.key == f"{P}/alive/_active/102"
        b_zid = str(b.zenoh.session.zid())
        stream = [*before]  # every sample the cloud got, in order
        while sum(1 for s in stream if str(s.timestamp.get_id()) == b_zid) < 5:
            stream.append(await next_sample(values, 5, "B's values"))
        origins = [str(s.timestamp.get_id()) for s in stream]
        first_b = origins.index(b_zid)
        assert set(origins[:first_b]) == {a_zid} and set(origins[first_b:]) == {b_zid}
        seqs = _seqs(stream)
        assert b.zenoh.pubs[("wire", "position")].seq_offset > 0, "B counted fewer frames"
        assert seqs == sorted(seqs), f"seq went back at the take-over: {seqs}"
        assert seqs[first_b] > seqs[first_b - 1], "B's first sample is a new one"
        assert len({(s.body["seq"], s.body["quality"]) for s in stream}) == len(stream)
        # events go on from the highest seq A published, also of events published before B
        # started (B learnt them from A's cache)
        display_state = f"{P}/display/state"
        a_last = a.zenoh.events.seq[display_state]
        assert a_last >= 1
        drain(states)
        b.master.nmt("display", "preop")
        ev = await sample_where(
            states, lambda s: s.key == display_state and s.body.get("nmt_state") == "pre_operational",
            5, "B's state event",
        )  # fmt: skip
        # after A's last: the take-over's own state event (the node adopted) may come between
        assert int(ev.body["seq"]) > a_last
        assert str(ev.timestamp.get_id()) == b_zid


async def test_the_duplicate_prefix_check_lets_the_partner_in_and_refuses_a_stranger() -> None:
    async with pair_running() as pair:
        stranger = gateway_of(
            make_config(
                [WIRE],
                zenoh={"mode": "peer", "listen": [], "connect": [pair.router]},
                modbus={"enabled": False},
                simulate={"nodes": []},
            ),
            simulate=False,
        )
        try:
            await stranger.start()  # starts, its Zenoh session closed: the prefix is the pair's
            assert stranger.zenoh is not None and not stranger.zenoh.up
            status = stranger.status()
            assert not status["ready"]
            assert any("another participant announces" in r for r in status["reasons"])
        finally:
            await stranger.stop()
        # the pair runs on, both members announced
        tokens = await pair.z.alive_tokens(f"{P}/alive/**")
        assert {f"{P}/alive/_gateway", f"{P}/alive/_active/101"} <= tokens
