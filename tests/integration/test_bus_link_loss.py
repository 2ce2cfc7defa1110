"""A gateway whose CAN connection is lost notices it, idles, and reopens with its backoff
(``canopen_gateway/bus/driver.py``, ``canopen_gateway/bus/socketcand_bus.py``), whatever the interface:

- ``socketcand`` on the pair's test bus (``tests/pair_bus.py``): the adapter unplugged (the
  server closes the connection and refuses it until plugged again: python-can's own socketcand
  bus would read "no frame" forever and spin);
- ``remote`` (python-can-remote): its server killed and started again.

"Not spinning" is measured between two events: the CPU time of the gateway's reader thread and
the receive calls it made while the bus was down and two or more reopen attempts were refused.
A cut cable (connection open, frames lost) is not a lost connection: the driver cannot notice it
(its sends succeed); the pair's role machine judges a member that hears nothing.
"""

from __future__ import annotations

import asyncio
import subprocess
import threading
import time
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager
from typing import Any

import can
import pytest

from canopen_gateway.bus.socketcand_bus import SocketcandBus
from tests.helpers import (
    free_port,
    master_running,
    start_can_remote,
    wait_can_remote,
    wait_until,
    wait_until_sync,
)
from tests.pair_bus import Frame, PairBus

MASTER_HEARTBEAT = 0x700 + 127  # the gateway's own heartbeat (master.node_id 127)


def own_heartbeat(f: Frame) -> bool:
    return f.sender == "gw" and f.cob_id == MASTER_HEARTBEAT


def reader_cpu_s() -> Callable[[], float]:
    """The CPU time of the gateway's CAN reader thread (this process), as a reader."""
    reader = next(t for t in threading.enumerate() if t.name == "can-reader")
    assert reader.ident is not None
    clock = time.pthread_getcpuclockid(reader.ident)
    return lambda: time.clock_gettime(clock)


def record_states(gw: Any) -> list[tuple[str, str]]:
    """Every state the driver reports through ``on_state`` from now on (the master's own
    listener still called)."""
    states: list[tuple[str, str]] = []
    inner = gw.driver.on_state

    def on_state(state: str, detail: str) -> None:
        states.append((state, detail))
        if inner is not None:
            inner(state, detail)

    gw.driver.on_state = on_state
    return states


@pytest.fixture
def recv_calls(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts calls of ``SocketcandBus._recv_internal`` (every receive the reader makes)."""
    calls = [0]
    real = SocketcandBus._recv_internal

    def counting(self: SocketcandBus, timeout: float | None) -> Any:
        calls[0] += 1
        return real(self, timeout)

    monkeypatch.setattr(SocketcandBus, "_recv_internal", counting)
    return calls


@pytest.fixture
def pair() -> Iterator[PairBus]:
    with PairBus() as b:
        yield b


async def test_an_unplugged_socketcand_adapter_takes_the_bus_down_idle_and_it_reopens_when_plugged(
    pair: PairBus, recv_calls: list[int]
) -> None:
    dev = pair.open_bus("dev")
    can_section = {**pair.can_section("gw"), "reopen_backoff_s": 0.2}
    async with master_running([], can=can_section) as gw:
        states = record_states(gw)
        await wait_until(lambda: pair.connected("gw"), 10, "the gateway on the bus")
        assert isinstance(gw.driver.bus, SocketcandBus)
        dev.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
        await wait_until(lambda: gw.image.counters["frames_in"] >= 1, 10, "a frame received")
        cpu = reader_cpu_s()

        pair.unplug("gw")
        await wait_until(lambda: gw.image.bus_state == "down", 5, "the bus down")
        assert states[0][0] == "down" and "closed the connection (EOF)" in states[0][1]
        assert gw.status()["bus"]["state"] == "down" and not gw.status()["ready"]
        # between two events: the bus down, then two more reopen attempts refused
        cpu_down, calls_down, refused = cpu(), recv_calls[0], pair.refused.get("gw", 0)
        await wait_until(lambda: pair.refused.get("gw", 0) >= refused + 2, 10, "two reopens refused")
        assert recv_calls[0] == calls_down  # no receive while the bus is down
        assert cpu() - cpu_down < 0.1  # the reader sleeps through the backoff
        assert gw.driver.reopen_attempts >= 2
        assert gw.driver.backoff_s(2) == 0.4  # doubling from can.reopen_backoff_s

        pair.plug("gw")
        await wait_until(lambda: gw.image.bus_state == "ok", 10, "the bus reopened")
        assert pair.joins["gw"] == 2 and gw.driver.reopens == 1
        assert states[-1] == ("ok", "")
        assert gw.status()["bus"] == {"state": "ok", "detail": ""}  # the old reason is not the state
        mark = gw.image.counters["frames_in"]
        dev.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
        await wait_until(lambda: gw.image.counters["frames_in"] > mark, 10, "frames again")
        assert gw.driver.reopen_attempts == 0  # a frame received: the next loss starts over
        # its own heartbeat reaches the bus again
        await asyncio.to_thread(pair.wait_for, own_heartbeat, after=len(pair.frames))


async def test_a_cut_cable_is_not_a_lost_connection_the_driver_stays_ok(pair: PairBus) -> None:
    """The cut member's sends succeed and it simply hears nothing: only the pair's role machine,
    which knows what it should hear, can tell (docs/redundancy.md)."""
    pair.open_bus("dev")
    async with master_running([], can=pair.can_section("gw")) as gw:
        await wait_until(lambda: pair.connected("gw"), 10, "the gateway on the bus")
        pair.cut("gw")
        mark = len(pair.frames)
        for _ in range(2):  # two heartbeats of its own lost on the cut cable
            lost = await asyncio.to_thread(pair.wait_for, own_heartbeat, after=mark)
            assert not lost.delivered
            mark = pair.frames.index(lost) + 1
        assert gw.image.bus_state == "ok" and gw.driver.reopens == 0


# ---------------------------------------------------------------------- python-can-remote
@asynccontextmanager
async def remote_server(port: int, channel: str) -> AsyncIterator[subprocess.Popen[bytes]]:
    """python-can-remote's server in a process of its own, listening (waited for off the loop:
    an in-process gateway's loop keeps running)."""
    proc = start_can_remote(port, channel)
    try:
        await asyncio.to_thread(wait_can_remote, proc, port)
        yield proc
    finally:
        proc.kill()
        proc.wait(timeout=10)


async def test_a_remote_can_server_killed_takes_the_bus_down_and_it_reopens_when_back() -> None:
    """python-can-remote's bus raises by itself when its server goes (the WebSocket reads EOF:
    ``WebsocketClosed``); reconnects are refused at once while nobody listens."""
    pytest.importorskip("can_remote")
    port, channel = free_port(), f"loss{free_port()}"
    can_section = {"interface": "remote", "channel": f"ws://127.0.0.1:{port}/",
                   "reopen_backoff_s": 0.2}  # fmt: skip
    async with remote_server(port, channel) as server:
        async with master_running([], can=can_section) as gw:
            states = record_states(gw)
            await wait_until(lambda: gw.image.bus_state == "ok", 10, "the bus open")
            cpu = reader_cpu_s()
            server.kill()
            server.wait(timeout=10)
            await wait_until(lambda: gw.image.bus_state == "down", 5, "the bus down")
            assert states[0][0] == "down" and "receive failed" in states[0][1]
            cpu_down, attempts = cpu(), gw.driver.reopen_attempts
            await wait_until(
                lambda: gw.driver.reopen_attempts >= attempts + 2, 10, "two reopens refused"
            )
            assert "Connection refused" in gw.driver.last_error
            assert cpu() - cpu_down < 0.1  # the reader sleeps through the backoff
            async with remote_server(port, channel):
                await wait_until(lambda: gw.image.bus_state == "ok", 20, "the bus reopened")
                assert gw.driver.reopens == 1 and states[-1] == ("ok", "")


def test_a_bus_that_cannot_open_at_start_is_said_down_and_opens_when_its_server_comes() -> None:
    """``on_state`` hears "down" from the start (the pair's role machine must know), and the
    reader retries a socketcand server nobody runs once per backoff, refused at once."""
    from canopen_gateway.bus.driver import BusDriver
    from canopen_gateway.image import ProcessImage

    with PairBus() as pair:
        pair.unplug("gw")  # the server refuses member gw, as a daemon without that channel
        states: list[tuple[str, str]] = []
        driver = BusDriver({**pair.can_section("gw")}, ProcessImage(), reopen_backoff_s=0.05,
                           on_state=lambda s, d: states.append((s, d)))  # fmt: skip
        driver.open()
        try:
            assert len(states) == 1 and states[0][0] == "down"  # the reader retries meanwhile
            assert "during the handshake" in states[0][1]
            wait_until_sync(lambda: pair.refused["gw"] >= 3, 10, "three attempts refused")
            pair.plug("gw")
            wait_until_sync(lambda: driver.state == "ok", 10, "the bus open")
            assert states[-1] == ("ok", "") and pair.connected("gw")
        finally:
            driver.close()
