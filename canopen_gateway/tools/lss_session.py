"""The blocking LSS session of the offline tool (``canopen-gateway lss``): requests on an own
connection to the bus, answered or timed out (with a note when several slaves answer), the LSS
state the slaves are in kept per bus in a state file between commands, and the configuration
state around each action.

The frames and their matching are ``canopen_gateway.bus.lss.master``'s; this module does the I/O. It is
for the offline command line only: while the gateway runs, LSS goes through the master
(``canopen_gateway.bus.lss.service``).

Imports: python-can, canopen_gateway.bus.lss.master, canopen_gateway.bus.lss.fastscan (the Fast Scan steps),
canopen_gateway.canopen.cia305. Nothing northbound.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from canopen_gateway.bus.lss import master as lss
from canopen_gateway.bus.lss.fastscan import FastScan
from canopen_gateway.canopen.cia305 import CS_IDENTIFY_SLAVE

#: After the first answer, how long to listen for more slaves answering the same request.
ANSWER_SETTLE_S = 0.05
#: Buses remembered in the state file (the oldest are dropped).
STATE_FILE_BUSES = 32


class LssFailed(Exception):
    """An LSS service or the Auto-ID failed (timeout, error answer)."""


# --------------------------------------------------------------------------- state left behind


@dataclass(frozen=True)
class LeftState:
    """The LSS state a command left the slaves of one bus in (manual 4.6 Table 10)."""

    mode: lss.LssMode = lss.LssMode.WAITING
    #: the one slave switched selectively; None: all slaves (switch state global)
    address: tuple[int, int, int, int] | None = None

    def describe(self) -> str:
        if self.address is None:
            return f"all slaves in {self.mode}"
        return f"slave {format_address(self.address)} in {self.mode}"


class LssStateFile:
    """Per bus, the state the last ``lss`` command left the slaves in, so the next command (a
    new process) continues from it. A missing or unreadable file means: all slaves waiting."""

    def __init__(self, path: Path, bus_key: str):
        self.path = path
        self.bus_key = bus_key

    @classmethod
    def for_bus(cls, bus_kwargs: dict[str, Any]) -> LssStateFile:
        base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
        parts = [f"{k}={bus_kwargs[k]}" for k in ("interface", "channel", "host", "port") if k in bus_kwargs]
        return cls(Path(base) / "canopen-gateway" / "lss-state.json", " ".join(parts))

    def _read_all(self) -> dict[str, Any]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) else {}

    def load(self) -> LeftState:
        entry = self._read_all().get(self.bus_key)
        if not isinstance(entry, dict):
            return LeftState()
        try:
            mode = lss.LssMode(entry["mode"])
            address = entry.get("address")
            return LeftState(mode, tuple(int(v) for v in address) if address else None)  # type: ignore[arg-type]
        except (TypeError, KeyError, ValueError):
            return LeftState()

    def save(self, state: LeftState) -> None:
        data = self._read_all()
        data.pop(self.bus_key, None)
        data[self.bus_key] = {
            "mode": str(state.mode),
            "address": list(state.address) if state.address else None,
        }
        data = dict(list(data.items())[-STATE_FILE_BUSES:])
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".tmp")
            tmp.write_text(json.dumps(data, indent=1), encoding="utf-8")
            tmp.replace(self.path)
        except OSError:
            pass  # a read-only home: the next command starts from "all waiting"


def format_address(address: tuple[int, int, int, int]) -> str:
    return ":".join(f"0x{v:X}" for v in address)


# --------------------------------------------------------------------------- bus session


class LssSession:
    """LSS requests on a python-can bus: frames out on 7E5h, answers matched on 7E4h."""

    def __init__(
        self,
        bus: can.BusABC,
        timeout_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        left: LeftState | None = None,
        settle_s: float = ANSWER_SETTLE_S,
    ):
        self.bus = bus
        self.clock = clock
        self.master = lss.LssMaster(timeout_s)
        self.settle_s = settle_s
        #: what the slaves are in now (what the previous command left, then what we did)
        self.left = left or LeftState()
        #: every answer to the last request (more than one: several slaves answered)
        self.answers: list[lss.LssValue] = []
        #: set while continuing with a slave a previous command left in configuration
        self.resumed: tuple[int, int, int, int] | None = None
        self.warnings: list[str] = []

    def send_frame(self, cob_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))

    def request(self, req: lss.LssRequest) -> lss.LssValue:
        """Send ``req``; its answer (None when the service has none). Raises LssFailed."""
        for frame in self.master.send(req, self.clock()):
            self.send_frame(lss.COB_ID_MASTER_TO_SLAVE, frame)
        if req.frames[0][0] == lss.CS_SWITCH_GLOBAL:
            self.left = LeftState(self.master.mode, None)
            self.resumed = None
        self.answers = []
        if req.answer_cs is None:
            return None
        while True:
            deadline = self.master.deadline_s
            now = self.clock()
            if deadline is None:
                raise LssFailed(f"LSS {req.service}: no request pending")  # pragma: no cover
            msg = self.bus.recv(timeout=max(0.0, deadline - now) + 0.001)
            now = self.clock()
            if (
                msg is not None
                and msg.arbitration_id == lss.COB_ID_SLAVE_TO_MASTER
                and not msg.is_remote_frame
                and not msg.is_error_frame
            ):
                for ev in self.master.on_frame(bytes(msg.data), now):
                    if isinstance(ev, lss.LssAnswered):
                        self.answers = [ev.value, *self._more_answers(req.answer_cs)]
                        return ev.value
            for ev in self.master.poll(now):
                if isinstance(ev, lss.LssTimedOut):
                    if self.resumed is not None:
                        hint = (
                            f"the slave {format_address(self.resumed)} the previous command "
                            "left in configuration does not answer (reset or powered off "
                            "since?); give address=VENDOR:PRODUCT:REVISION:SERIAL"
                        )
                        self.left = LeftState()
                    else:
                        hint = "no LSS slave in configuration state?"
                    raise LssFailed(
                        f"LSS {req.service}: no answer on 0x{lss.COB_ID_SLAVE_TO_MASTER:03X} "
                        f"within {ev.timeout_s:g} s ({hint})"
                    )

    def _more_answers(self, cs: int) -> list[lss.LssValue]:
        """Further answers with ``cs`` within ``settle_s``: other slaves in configuration."""
        more: list[lss.LssValue] = []
        deadline = self.clock() + self.settle_s
        while (left := deadline - self.clock()) > 0:
            msg = self.bus.recv(timeout=left)
            if (
                msg is not None
                and msg.arbitration_id == lss.COB_ID_SLAVE_TO_MASTER
                and not msg.is_remote_frame
                and not msg.is_error_frame
                and len(msg.data) > 0
                and msg.data[0] == cs
            ):
                try:
                    more.append(lss.decode_answer(bytes(msg.data))[1])
                except ValueError:
                    continue
        return more

    def configure(self, req: lss.LssRequest) -> None:
        """A configure / store service; raises LssFailed when the slave answers an error."""
        answer = self.request(req)
        if len(self.answers) > 1:
            self.warnings.append(
                f"warning: {len(self.answers)} LSS slaves answered {req.service}: more than one "
                "is in the LSS configuration state and each of them took it; address one with "
                "address=VENDOR:PRODUCT:REVISION:SERIAL"
            )
        if isinstance(answer, lss.ConfigAnswer) and not answer.ok:
            raise LssFailed(f"LSS {req.service} refused: {answer.text}")

    def wait_frame(self, cob_id: int, timeout_s: float) -> can.Message | None:
        """The next data frame on ``cob_id`` within ``timeout_s`` (None on timeout)."""
        deadline = self.clock() + timeout_s
        while True:
            left = deadline - self.clock()
            if left <= 0:
                return None
            msg = self.bus.recv(timeout=left)
            if (
                msg is not None
                and msg.arbitration_id == cob_id
                and not msg.is_remote_frame
                and not msg.is_error_frame
            ):
                return msg

    @contextmanager
    def configuration_state(
        self, address: tuple[int, int, int, int] | None, keep: bool = False
    ) -> Iterator[None]:
        """Slave(s) in LSS configuration for the block; back to waiting afterwards unless
        ``keep``. By address: all to waiting, then switch state selective (Table 10: a slave
        already in configuration ignores the selective switch). Without: the slave a previous
        command left in configuration, else all slaves by switch state global."""
        if address is not None:
            self.select(address)
        elif self.left.mode is lss.LssMode.CONFIGURATION and self.left.address is not None:
            self.master.resume(lss.LssMode.CONFIGURATION)
            self.resumed = self.left.address
        else:
            self.request(lss.switch_state_global(True))
        ok = False
        try:
            yield
            ok = True
        finally:
            if not keep or not ok:
                self.request(lss.switch_state_global(False))

    def fast_scan(self, scan: FastScan, wait_s: float) -> FastScan:
        """Run a CiA 305 Fast Scan (``canopen_gateway.bus.lss.fastscan``): each frame, then the whole
        ``wait_s`` for 4Fh answers (several slaves answer one step together; a late one must
        not count for the next). The slave found is left in configuration."""
        while (frame := scan.next_frame()) is not None:
            self.send_frame(lss.COB_ID_MASTER_TO_SLAVE, frame)
            scan.answered(self._identified(wait_s))
        if scan.found is not None:
            self.master.resume(lss.LssMode.CONFIGURATION)
            self.left = LeftState(lss.LssMode.CONFIGURATION, scan.found)
        return scan

    def _identified(self, wait_s: float) -> bool:
        """Whether any slave answered 4Fh (identify slave) within ``wait_s``."""
        deadline = self.clock() + wait_s
        got = False
        while (left := deadline - self.clock()) > 0:
            msg = self.bus.recv(timeout=left)
            if (
                msg is not None
                and msg.arbitration_id == lss.COB_ID_SLAVE_TO_MASTER
                and not msg.is_remote_frame
                and len(msg.data) > 0
                and msg.data[0] == CS_IDENTIFY_SLAVE
            ):
                got = True
        return got

    def select(self, address: tuple[int, int, int, int]) -> None:
        """Only the slave with ``address`` in configuration (04h 00h, then 40h..43h)."""
        self.request(lss.switch_state_global(False))
        self.request(lss.switch_state_selective(*address))
        self.left = LeftState(lss.LssMode.CONFIGURATION, address)


