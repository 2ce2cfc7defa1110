"""LSS (CiA 305) while the gateway runs: a service of the master, on the master's own connection
to the bus. The web console (and any adapter) asks through the command service; no second
``can.Bus`` is opened, so it works on interfaces that allow one connection only.

Rule 1: the frames and their matching are ``bus.lss.master.LssMaster``'s (no I/O); this module
only sends its frames through the driver, feeds it the 7E4h frames the reader hands to the
event loop (``Master._post``, the one hand-off) and wakes it at its deadline.
Rule 2: one LSS session at a time (a lock): an inquiry switches the slave(s) to configuration,
asks, and switches them back to waiting, whatever happens in between; so does a Fast Scan
(``fast_scan``: the steps of ``bus.lss.fastscan.FastScan``, each followed by a wait for the 4Fh
answers, then the node id given to the slave found, and the next).

Imports: bus.lss.master, bus.lss.fastscan, canopen.cia301, canopen.cia305, errors, python-can
(the message type), asyncio. Nothing northbound.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

import can

from canopen_gateway.bus.lss.fastscan import FastScan
from canopen_gateway.bus.lss.master import (
    INQUIRE_ORDER,
    ConfigAnswer,
    LssAnswered,
    LssMaster,
    LssMode,
    LssRequest,
    LssTimedOut,
    LssValue,
    configure_node_id,
    inquire,
    store_configuration,
    switch_state_global,
    switch_state_selective,
)
from canopen_gateway.canopen.cia301 import COB_LSS_MASTER, COB_LSS_SLAVE
from canopen_gateway.canopen.cia305 import CS_IDENTIFY_SLAVE
from canopen_gateway.errors import LssFailed

#: a Fast Scan's address parts given in advance (vendor id, product code, revision; None: scanned)
Known = tuple[int | None, int | None, int | None, int | None]


class LssService:
    """LSS requests through the running master (see the module docstring).

    ``send(cob_id, data)`` queues a frame (the driver's), ``post(fn, *args)`` hands a call to
    the event loop (the master's inbox), ``clock()`` is the bus clock and ``frame_time(msg)``
    a frame's time on it.
    """

    def __init__(
        self,
        send: Callable[[int, bytes], None],
        post: Callable[..., None],
        clock: Callable[[], float],
        frame_time: Callable[[can.Message], float],
        timeout_s: float = 0.5,
    ):
        self.machine = LssMaster(timeout_s)
        self._send = send
        self._post = post
        self._clock = clock
        self._frame_time = frame_time
        self._waiting: asyncio.Future[LssValue] | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._lock: asyncio.Lock | None = None
        #: 7E4h frames that answered nothing pending (a late answer, another master's)
        self.ignored = 0
        #: a Fast Scan step heard a 4Fh (identify slave) since it was sent
        self._identified = False

    # ------------------------------------------------------------------ reader thread
    def reader_handler(self) -> Callable[[can.Message], None]:
        """The reader's handler of 7E4h: hands the frame to the event loop."""
        post, frame_time, on_frame = self._post, self._frame_time, self._on_frame

        def handle(msg: can.Message) -> None:
            if msg.is_remote_frame or msg.is_error_frame:
                return
            post(on_frame, bytes(msg.data), frame_time(msg))

        return handle

    # ------------------------------------------------------------------ event loop
    def _on_frame(self, data: bytes, now: float) -> None:
        if data[:1] == bytes([CS_IDENTIFY_SLAVE]):  # a Fast Scan step's answer: whoever sent it
            self._identified = True
            return
        for ev in self.machine.on_frame(data, now):
            if isinstance(ev, LssAnswered):
                self._resolve(ev.value, None)
            else:
                self.ignored += 1

    def _poll(self) -> None:
        self._timer = None
        for ev in self.machine.poll(self._clock()):
            if isinstance(ev, LssTimedOut):
                self._resolve(
                    None,
                    LssFailed(
                        f"LSS {ev.request.service}: no answer on 0x{COB_LSS_SLAVE:03X} within "
                        f"{ev.timeout_s:g} s (no LSS slave in configuration state?)"
                    ),
                )
        self._arm()

    def _arm(self) -> None:
        deadline = self.machine.deadline_s
        if deadline is None or self._timer is not None:
            return
        loop = asyncio.get_running_loop()
        # the deadline is on the bus clock, which may lag the loop's clock
        self._timer = loop.call_later(max(0.0, deadline - self._clock()) + 0.001, self._poll)

    def _resolve(self, value: LssValue, exc: BaseException | None) -> None:
        fut, self._waiting = self._waiting, None
        if fut is None or fut.done():
            return
        if exc is not None:
            fut.set_exception(exc)
        else:
            fut.set_result(value)

    async def request(self, req: LssRequest) -> LssValue:
        """Send ``req``; its answer (None for a service without one). Raises LssFailed,
        ``LssBusy`` (a request is pending), ``LssStateError`` (Table 10) or ``can.CanError``
        (the bus is down)."""
        frames = self.machine.send(req, self._clock())
        try:
            for frame in frames:
                self._send(COB_LSS_MASTER, frame)
        except can.CanError:
            self.machine.cancel()  # nothing went out: nothing to wait for
            raise
        if req.answer_cs is None:
            return None
        fut: asyncio.Future[LssValue] = asyncio.get_running_loop().create_future()
        self._waiting = fut
        self._arm()
        return await fut

    def busy(self) -> bool:
        """An LSS session is running."""
        return self._lock is not None and self._lock.locked()

    async def inquire_all(
        self, address: tuple[int, int, int, int] | None = None
    ) -> dict[str, Any]:
        """Vendor id, product code, revision, serial and node id (CiA 305; SGH10 manual 4.6.3)
        of the one slave in configuration: the slave at ``address`` (switch state selective),
        else every slave (switch state global). The slaves are back in waiting afterwards."""
        if self._lock is None:
            self._lock = asyncio.Lock()
        async with self._lock:
            if address is not None:
                await self.request(switch_state_global(False))
                await self.request(switch_state_selective(*address))
            else:
                await self.request(switch_state_global(True))
            try:
                return {item: await self.request(inquire(item)) for item in INQUIRE_ORDER}
            finally:
                self._waiting = None
                self.machine.cancel()  # an unanswered inquiry does not block the switch back
                await self.request(switch_state_global(False))

    async def fast_scan(
        self, known: Known, wait_s: float, first_node_id: int | None = None, count: int = 1,
        store: bool = False,
    ) -> dict[str, Any]:  # fmt: skip
        """CiA 305 Fast Scan: the LSS address of the unconfigured slave with the lowest one
        (the parts in ``known`` confirmed, not scanned); with ``first_node_id`` that slave is
        given the node id (11h; ``store``: 17h) and switched to waiting, where it no longer
        takes part, and the next is scanned, ``count`` times. Each step waits ``wait_s`` for
        4Fh answers (several slaves answering together are one answer). The slaves are back
        in waiting afterwards; a node id given applies at their next NMT reset communication.
        ``{"found": [{"address", "node_id", "stored"}], "frames", "failed"}`` (``failed``: why
        a later scan found none); LssFailed when the first finds none."""
        if count > 1 and first_node_id is None:
            raise ValueError("count needs a first node id (each device found is given the next)")
        if self._lock is None:
            self._lock = asyncio.Lock()
        found: list[dict[str, Any]] = []
        frames, failed = 0, None
        async with self._lock:
            try:
                for k in range(count):
                    scan = await self._scan(FastScan(known), wait_s)
                    frames += scan.frames
                    if scan.found is None:
                        if not found:
                            raise LssFailed(f"LSS fast scan: {scan.failed}")
                        failed = scan.failed
                        break
                    self.machine.resume(LssMode.CONFIGURATION)  # the slave found is in it
                    entry: dict[str, Any] = {"address": scan.found, "node_id": None, "stored": False}
                    if first_node_id is not None:
                        await self._configure(configure_node_id(first_node_id + k))
                        entry["node_id"] = first_node_id + k
                        if store:
                            await self._configure(store_configuration())
                            entry["stored"] = True
                    found.append(entry)
                    await self.request(switch_state_global(False))  # the next takes part alone
            finally:
                self._waiting = None
                self.machine.cancel()
                await self.request(switch_state_global(False))
        return {"found": found, "frames": frames, "failed": failed}

    async def _scan(self, scan: FastScan, wait_s: float) -> FastScan:
        """Each frame of ``scan``, then the whole ``wait_s`` for 4Fh answers."""
        while (frame := scan.next_frame()) is not None:
            self._identified = False
            self._send(COB_LSS_MASTER, frame)
            await asyncio.sleep(wait_s)
            scan.answered(self._identified)
        return scan

    async def _configure(self, req: LssRequest) -> None:
        answer = await self.request(req)
        if isinstance(answer, ConfigAnswer) and not answer.ok:
            raise LssFailed(f"LSS {req.service}: {answer.text}")

    def stop(self) -> None:
        """The gateway stops: a waiting request fails."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._resolve(None, LssFailed("gateway stopping"))
