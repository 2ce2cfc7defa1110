"""The output watchdog's driver (``modbus.watchdog.OutputWatchdog`` is its machine): on the
event loop beside the Modbus server, fed by the connections of clients that may write (their
requests, connections and disconnections); its timer a ``loop.call_at`` at the machine's next
deadline; a trip writes the nodes' safe outputs (``modbus.safe_outputs``) through the command
service.

Imports: commands, config, device.resolved, image (the nodes' output records), modbus.safe_outputs,
modbus.watchdog.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from canopen_gateway.commands import CommandService
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode
from canopen_gateway.image import ProcessImage
from canopen_gateway.modbus.safe_outputs import safe_outputs
from canopen_gateway.modbus.watchdog import TIMEOUT, OutputWatchdog, WatchdogState

log = logging.getLogger("gateway.modbus")


class OutputWatchdogDriver:
    """Drives the output watchdog's machine (``modbus.watchdog.OutputWatchdog``) on the event
    loop, beside the server: the connections of clients that may write report their requests,
    connections and disconnections here; its timer is a ``loop.call_at`` at the machine's next
    deadline (armed only while the server serves); a trip writes the nodes' safe outputs
    (``modbus.safe_outputs``) through the command service."""

    def __init__(
        self, cfg: Config, nodes: dict[str, ResolvedNode], commands: CommandService,
        image: ProcessImage,
    ) -> None:
        self.commands = commands
        self.image = image  # its output records: the writes made or heard (a pair's take-over)
        self.watchdog_ms = cfg.modbus.watchdog_ms
        self.machine = OutputWatchdog(
            cfg.modbus.watchdog_ms / 1000.0, cfg.modbus.watchdog_on_disconnect
        )
        self.safe_plan: dict[str, dict[str, Any]] = {}
        if self.machine.enabled:
            for n in cfg.nodes:
                values = safe_outputs(nodes[n.name].lp, n)
                if values:
                    self.safe_plan[n.name] = values
        self.last_safe: dict[str, str] = {}  # per node: "safe" or why not, at the last trip
        #: the server listens: the timer may be armed, a client's disconnection counts
        self.serving = False
        self._timer: asyncio.TimerHandle | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    def writer_connected(self) -> None:
        self.machine.on_writer_connect(asyncio.get_running_loop().time())

    def request_seen(self) -> None:
        """Every request of a client that may write (any unit, any function, any outcome)
        feeds the watchdog."""
        wd = self.machine
        if not wd.enabled:
            return
        wd.on_request(asyncio.get_running_loop().time())
        if self._timer is None:
            self._schedule()

    def set_mastering(self, mastering: bool) -> None:
        """The gateway started or stopped mastering the bus (a hot-standby pair's role; the
        app calls it at start and at every role change). On the standby the watchdog is
        STANDBY (commands refuse: no safe outputs to write, no timer); when the gateway becomes
        active it counts from the PLC's last sign: a request of a client that may write to
        this gateway, or the last write to an output made or heard on the bus (the nodes'
        output records, on the bus clock: the loop's monotonic clock); none: as at start."""
        if mastering == (self.machine.state is not WatchdogState.STANDBY):
            return
        written = [n.outputs.monotonic for n in self.image.nodes.values() if n.outputs.seq]
        self.machine.on_mastering(mastering, max(written, default=None))
        self._cancel_timer()
        self._schedule()  # armed from the PLC's last sign: due now, or later

    def writer_gone(self) -> None:
        if not self.serving:
            return  # the server stops: its clients did not go away
        reason = self.machine.on_writer_disconnect(asyncio.get_running_loop().time())
        if reason is not None:
            self._trip(reason)

    def stop(self) -> None:
        """The server stops: no timer, and its clients' disconnections are no trip."""
        self.serving = False
        self._cancel_timer()

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _schedule(self) -> None:
        deadline = self.machine.next_deadline()
        if deadline is not None and self.serving:
            self._timer = asyncio.get_running_loop().call_at(deadline, self._tick)

    def _tick(self) -> None:
        self._timer = None
        reason = self.machine.tick(asyncio.get_running_loop().time())
        if reason is not None:
            self._trip(reason)
        else:
            self._schedule()  # a request came since: the deadline moved

    def _trip(self, reason: str) -> None:
        ms = self.watchdog_ms
        if reason == TIMEOUT:
            why = f"no request of a client allowed to write for {ms} ms"
        elif ms:
            why = f"the last client allowed to write disconnected; no request of one for {ms} ms"
        else:
            why = "the last client allowed to write disconnected"
        log.warning(
            "Modbus output watchdog tripped (%s): writing the safe outputs of %s",
            why,
            ", ".join(self.safe_plan) or "no node (none has a safe value)",
        )
        task = asyncio.get_running_loop().create_task(self._write_safe())
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _write_safe(self) -> None:
        self.last_safe = await self.commands.write_safe_outputs(self.safe_plan)
