"""A python-can bus on the gateway's own connection, for a tool that needs a ``can.BusABC``
(python canopen's SDO client in ``bus.scan``) while the gateway runs.

Receiving: a tap of the driver (``BusDriver.add_tap``) hands every frame the reader receives
to a bounded queue, from the moment the ``TapBus`` is made until ``shutdown``; ``recv`` takes
from that queue on the thread that reads the bus for the tool (in the scan: python-can's
``Notifier`` thread). The tap is the one hand-off (CAN reader thread -> that thread): it
never blocks the reader; when the tool falls ``QUEUE_MAX`` frames behind, newer frames are
dropped and counted in ``lost``.

Sending: ``send`` queues the frame for the driver's sender thread, as every frame of the gateway
goes out: no second connection is opened, so it works on every interface, also those that allow
one connection per channel (PCAN, Kvaser, IXXAT, slcan). While the bus is down ``send`` raises
``can.CanOperationError``. Frames sent this way are not received back (the gateway does not
receive what it sends).

Imports: python-can, bus.driver.
"""

from __future__ import annotations

import queue

import can

from canopen_gateway.bus.driver import BusDriver

QUEUE_MAX = 20_000  # frames: 2 s of a saturated 1 Mbit/s bus


class TapBus(can.BusABC):
    """``can.BusABC`` over a running ``BusDriver`` (see the module docstring)."""

    def __init__(self, driver: BusDriver, queue_max: int = QUEUE_MAX):
        self.driver = driver
        self._queue: queue.Queue[can.Message] = queue.Queue(queue_max)
        self.lost = 0  # written by the reader thread only
        super().__init__(channel="gateway")
        self.channel_info = "the gateway's own connection"
        driver.add_tap(self._on_frame)

    def _on_frame(self, msg: can.Message) -> None:
        """The tap: CAN reader thread."""
        try:
            self._queue.put_nowait(msg)
        except queue.Full:
            self.lost += 1

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            if timeout is not None and timeout <= 0:
                return self._queue.get_nowait(), False
            return self._queue.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_extended_id:  # the driver sends CANopen's 11-bit identifiers only
            raise can.CanOperationError("a 29-bit identifier is not sent on this connection")
        self.driver.send(
            msg.arbitration_id,
            bytes(msg.data),
            rtr=msg.is_remote_frame,
            dlc=msg.dlc,
        )

    def shutdown(self) -> None:
        self.driver.remove_tap(self._on_frame)
        super().shutdown()
