"""Error control against simulated devices and raw frames on a virtual bus: heartbeat consumer
timeout, node guarding (life time, toggle bit), EMCY with the profile's texts."""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any

import can

from canopen_gateway.app import Gateway
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.image import Quality
from tests.helpers import master_running as running
from tests.helpers import node_operational as operational
from tests.helpers import wait_until


async def _lost_after(gw: Gateway, name: str, limit_s: float) -> None:
    """Silence the simulated node and wait until the gateway reports it lost (the timeout
    edges themselves are checked on a fake clock in tests/unit/test_supervision.py and
    tests/unit/test_node.py)."""
    sim = gw.sim.nodes[name]
    health = gw.image.nodes[name].health
    gw.sim.runner.call(lambda now: sim.silence())
    await wait_until(lambda: not health.alive, limit_s, f"{name} lost")


async def test_silent_heartbeat_node_is_lost_within_the_consumer_timeout_and_back_after() -> None:
    # heartbeat 100 ms (profile), consumer timeout 1.5 x 100 ms
    async with running([{"name": "wire", "node_id": 1, "profile": "sgh10"}]) as gw:
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        health = gw.image.nodes["wire"].health
        await _lost_after(gw, "wire", 2.0)
        assert health.loss_count == 1
        assert health.lifecycle == "waiting"
        node = gw.image.nodes["wire"]
        assert node.quality(node.signals["position"]) == Quality.STALE
        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.unsilence(now))
        await wait_until(lambda: operational(gw, "wire"), 5, "wire back and operational")
        assert health.loss_count == 1
        assert gw.master.nodes["wire"].lifecycle.configurations == 2  # found again, reconfigured


async def test_silent_guarded_node_is_lost_after_the_life_time_and_back_after() -> None:
    node = {
        "name": "rotary",
        "node_id": 3,
        "profile": "posi_plus",
        "supervision": "guarding",
        "guard_time_ms": 100,
        "life_time_factor": 3,
    }
    async with running([node]) as gw:
        await wait_until(lambda: operational(gw, "rotary"), 5, "rotary operational")
        rt = gw.master.nodes["rotary"]
        assert gw.sim.nodes["rotary"].get(0x1017, 0) == 0  # guarding, so no heartbeat
        assert rt.guard is not None and rt.guard.rtr_sent > 0
        # an RTR on 703h (DLC 1) every guard time
        observer = can.Bus(interface="virtual", channel=gw.cfg.can.channel)
        try:
            rtrs = await asyncio.to_thread(_frames, observer, 0x703, True, 4)
        finally:
            observer.shutdown()
        assert all(m.dlc == 1 for m in rtrs)
        await _lost_after(gw, "rotary", 2.0)
        sim = gw.sim.nodes["rotary"]
        gw.sim.runner.call(lambda now: sim.unsilence(now))
        await wait_until(lambda: operational(gw, "rotary"), 5, "rotary back and operational")
        assert rt.image.health.loss_count == 1


def _frames(bus: can.BusABC, cob: int, rtr: bool, count: int, timeout_s: float = 3.0) -> list:
    out: list[can.Message] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < count and time.monotonic() < deadline:
        msg = bus.recv(timeout=0.05)
        if msg is not None and msg.arbitration_id == cob and msg.is_remote_frame == rtr:
            out.append(msg)
    assert len(out) == count, f"only {len(out)} frames 0x{cob:03X}"
    return out


class StuckToggleNode:
    """A raw-frame node 3 that answers every guarding RTR with toggle 0, OPERATIONAL (05h)."""

    def __init__(self, channel: str, node_id: int = 3):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.cob = 0x700 + node_id
        self.answers = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> StuckToggleNode:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.02)
            if msg is not None and msg.arbitration_id == self.cob and msg.is_remote_frame:
                self.bus.send(
                    can.Message(arbitration_id=self.cob, data=b"\x05", is_extended_id=False)
                )
                self.answers += 1


async def test_guarding_answers_that_never_toggle_make_the_node_lost() -> None:
    node = {
        "name": "rotary",
        "node_id": 3,
        "profile": "posi_plus",
        "supervision": "guarding",
        "guard_time_ms": 50,
        "life_time_factor": 3,
        "configure": False,
    }
    async with running([node], simulate={"nodes": []}, master={"sdo_timeout_s": 0.1}) as gw:
        rt = gw.master.nodes["rotary"]
        health = rt.image.health
        with StuckToggleNode(gw.cfg.can.channel) as device:
            # the first answer (toggle 0) is valid: alive
            await wait_until(lambda: health.alive, 2, "first guarding answer")
            # every later answer repeats toggle 0: not valid, the life time (150 ms) runs out
            await wait_until(lambda: not health.alive, 2, "lost by toggle errors")
            assert device.answers >= 3
            assert rt.guard is not None
            assert rt.guard.toggle_errors >= 2
            assert health.loss_count == 1


async def test_emcy_shows_the_profile_text_current_errors_and_0000h_clears_them() -> None:
    async with running([{"name": "wire", "node_id": 1, "profile": "sgh10"}]) as gw:
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        rt = gw.master.nodes["wire"]
        h = rt.image.health
        sim = gw.sim.nodes["wire"]
        gw.sim.runner.call(lambda now: sim.raise_emcy(0xFF05, 0x81, now=now))
        await wait_until(lambda: h.current_errors == [0xFF05], 2, "EMCY FF05h current")
        assert h.last_emcy is not None
        assert h.last_emcy.text == "Position value error"  # SGH10 manual 4.5.1 table 9
        assert h.last_emcy.register == 0x81
        gw.sim.runner.call(lambda now: sim.raise_emcy(0xFF15, 0x81, now=now))
        await wait_until(lambda: h.current_errors == [0xFF05, 0xFF15], 2, "two current errors")
        gw.sim.runner.call(lambda now: sim.clear_emcy(0xFF05, now=now))
        gw.sim.runner.call(lambda now: sim.clear_emcy(0xFF15, now=now))
        await wait_until(lambda: h.current_errors == [], 2, "0000h clears the current errors")
        assert h.last_emcy.code == 0x0000
        assert [e.code for e in rt.emcy.history][:3] == [0xFF05, 0xFF15, 0x0000]
        assert h.emcy_count >= 3
        assert operational(gw, "wire")  # an EMCY is not a loss


async def test_heartbeat_consumer_timeout_is_the_configured_multiple_of_the_producer_time() -> None:
    nodes = [{"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 50}]
    async with running(nodes, master={"heartbeat_timeout_multiple": 4}) as gw:
        rt = gw.master.nodes["wire"]
        assert rt.hb is not None
        assert rt.hb.timeout_s == 0.2
        await wait_until(lambda: operational(gw, "wire"), 5, "wire operational")
        assert gw.sim.nodes["wire"].get(0x1017, 0) == 50
        # alive over several producer periods (no false loss)
        seen = rt.hb.heartbeats
        await wait_until(lambda: rt.hb.heartbeats >= seen + 6, 2, "six more heartbeats")
        assert rt.image.health.loss_count == 0


class _CountingLoop:
    """The master's loop with its cross-thread wake-ups counted."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self._loop = loop
        self.wakeups = 0

    def call_soon_threadsafe(self, *args: Any) -> Any:
        self.wakeups += 1
        return self._loop.call_soon_threadsafe(*args)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loop, name)


async def test_repeated_heartbeats_of_a_steady_node_do_not_wake_the_loop_but_keep_it_alive() -> None:
    """A heartbeat that repeats the previous one of an alive, operational node changes nothing
    before its deadline: it is queued without a wake-up and drained by the node's deadline timer
    before any timeout is judged. A heartbeat that says something new wakes the loop at once."""
    nodes = [{"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 50}]
    async with running(nodes, master={"sync_period_ms": 0}) as gw:
        rt = gw.master.nodes["wire"]
        await wait_until(lambda: operational(gw, "wire") and rt.steady, 5, "wire steady")
        counting = _CountingLoop(gw.master.loop)
        gw.master.loop = counting  # type: ignore[assignment]
        seen = rt.hb.heartbeats
        await wait_until(lambda: rt.hb.heartbeats >= seen + 10, 3, "ten more heartbeats")
        assert counting.wakeups == 0  # every one drained by the node's own timer
        assert rt.image.health.alive and rt.image.health.loss_count == 0
        # NMT stop: the device's next heartbeat says STOPPED and wakes the loop
        gw.master.nmt("wire", "stop")
        await wait_until(lambda: rt.image.health.nmt_state == NmtState.STOPPED, 2, "stopped seen")
        assert counting.wakeups >= 1
