"""Turns on the event loop (``canopen_gateway.runtime.turns.LoopTurns``): one piece of northbound work per loop
iteration, so the loop polls its sockets (a PLC's request) between two pieces; bounded."""

from __future__ import annotations

import asyncio
import socket
import time

from canopen_gateway.runtime.turns import LoopTurns


class Iterations:
    """Counts the loop's iterations: a callback that runs once per iteration, re-armed."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.n = 0
        self.loop = loop
        self.running = True
        loop.call_soon(self._tick)

    def _tick(self) -> None:
        self.n += 1
        if self.running:
            self.loop.call_soon(self._tick)


async def test_a_burst_of_clients_gets_one_turn_per_loop_iteration() -> None:
    turns = LoopTurns()
    it = Iterations(asyncio.get_running_loop())
    granted_at: list[int] = []

    async def client() -> None:
        assert await turns.turn()
        granted_at.append(it.n)

    await asyncio.gather(*(client() for _ in range(20)))
    it.running = False
    assert len(granted_at) == 20
    assert len(set(granted_at)) == 20  # never two pieces in one iteration
    assert turns.granted == 20 and turns.waiting == 0


async def test_a_socket_read_is_served_between_two_turns() -> None:
    """A ready socket is read in the loop's next iteration: two clients' pieces never both run
    before it (a burst does not hold a PLC's request up)."""
    turns = LoopTurns()
    loop = asyncio.get_running_loop()
    order: list[str] = []
    rsock, wsock = socket.socketpair()
    rsock.setblocking(False)
    loop.add_reader(rsock.fileno(), lambda: (rsock.recv(16), order.append("plc")))
    try:

        async def client(i: int) -> None:
            await turns.turn()
            order.append(f"piece{i}")
            if i == 0:
                wsock.send(b"x")  # the PLC's request arrives during the first piece

        await asyncio.gather(*(client(i) for i in range(5)))
        await asyncio.sleep(0)
    finally:
        loop.remove_reader(rsock.fileno())
        rsock.close()
        wsock.close()
    assert order.index("plc") <= 2  # after piece 0, and at most one more piece
    assert order.count("plc") == 1


async def test_past_the_bound_a_client_is_refused_at_once_and_counted() -> None:
    turns = LoopTurns(waiting_max=2)
    results: list[bool] = []

    async def client() -> None:
        results.append(await turns.turn())

    await asyncio.gather(*(client() for _ in range(4)))
    # the first gets its turn at once, two wait, the fourth is refused
    assert sorted(results) == [False, True, True, True]
    assert turns.refused == 1
    # unbounded clients (a live page, bounded by its own limit) always wait
    turns = LoopTurns(waiting_max=1)
    assert all(await asyncio.gather(*(turns.turn(bounded=False) for _ in range(4))))


async def test_a_client_that_goes_away_gives_its_turn_up() -> None:
    turns = LoopTurns()
    first = asyncio.ensure_future(turns.turn())
    gone = asyncio.ensure_future(turns.turn())
    after = asyncio.ensure_future(turns.turn())
    await asyncio.sleep(0)  # the three ran once: the first has its turn, two wait
    assert first.done() and turns.waiting == 2
    gone.cancel()
    assert await after
    assert gone.cancelled() and turns.waiting == 0
    assert turns.granted == 2


async def test_turns_are_spread_out_in_time_by_the_minimum_gap() -> None:
    turns = LoopTurns(min_gap_s=0.002)
    loop = asyncio.get_running_loop()
    at: list[float] = []

    async def client() -> None:
        await turns.turn()
        at.append(loop.time())

    await asyncio.gather(*(client() for _ in range(5)))
    gaps = [b - a for a, b in zip(at, at[1:], strict=False)]
    slack = time.get_clock_info("monotonic").resolution
    assert len(gaps) == 4 and all(g >= 0.002 - slack for g in gaps)
