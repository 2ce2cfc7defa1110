"""One node's SDO channel: transfers queued and run one at a time, in order (CiA 301: one
SDO server channel per node; a second request while one runs would be taken as part of it).

The channel runs ``sdo_client.SdoTransfer`` machines and tells its owner (``bus.node.node.Node``)
when one finishes; what a finished transfer means (a boot step, a probe, a command) is the
owner's business. No I/O, no clock: frames out, ``now`` in.

Imports: bus.sdo.client, bus.events, canopen.cia301, canopen.objref.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from canopen_gateway.bus.events import Send
from canopen_gateway.bus.sdo.client import SdoTransfer
from canopen_gateway.canopen.cia301 import COB_SDO_RX
from canopen_gateway.canopen.objref import ObjRef


@dataclass
class SdoJob:
    token: int
    obj: ObjRef
    data: bytes | None  # None: upload
    purpose: str  # "boot" | "probe" | "refresh" | "reference" | "user"
    arg: Any = None


Finished = tuple[SdoJob, SdoTransfer]


class SdoChannel:
    def __init__(self, node_id: int, timeout_s: float, retries: int):
        self.node_id = node_id
        self.timeout_s = timeout_s
        self.retries = retries
        self.jobs: deque[SdoJob] = deque()
        self.running: Finished | None = None
        self._tokens = 0
        # when work waiting in ``jobs`` became startable (nothing running): the owner's next
        # deadline, so queued work never waits for an unrelated timer (None: nothing waits)
        self._ready_since: float | None = None

    # -- queries
    @property
    def idle(self) -> bool:
        return self.running is None

    @property
    def busy(self) -> bool:
        return self.running is not None or bool(self.jobs)

    def next_deadline(self) -> float | None:
        """The running transfer's timeout; with none running and work queued, the moment the
        work was queued (i.e. due now): queued work is started by the owner's next tick."""
        if self.running is not None:
            return self.running[1].next_deadline()
        return self._ready_since if self.jobs else None

    def find(self, purpose: str) -> SdoJob | None:
        if self.running is not None and self.running[0].purpose == purpose:
            return self.running[0]
        return next((j for j in self.jobs if j.purpose == purpose), None)

    # -- queue
    def token(self) -> int:
        self._tokens += 1
        return self._tokens

    def queue(
        self, obj: ObjRef, data: bytes | None, purpose: str, now: float, arg: Any = None
    ) -> int:
        """Queue a transfer at ``now``; the owner starts it when the channel is free."""
        token = self.token()
        self.jobs.append(SdoJob(token, obj, data, purpose, arg))
        if self.running is None and self._ready_since is None:
            self._ready_since = now
        return token

    def drop(self, keep: Callable[[SdoJob], bool]) -> None:
        self.jobs = deque(j for j in self.jobs if keep(j))
        if not self.jobs:
            self._ready_since = None

    # -- transfers
    def start(self, job: SdoJob, now: float) -> list[Send]:
        assert self.running is None
        tr = SdoTransfer(
            job.obj.index, job.obj.sub, job.data, timeout_s=self.timeout_s, retries=self.retries
        )
        self.running = (job, tr)
        self._ready_since = None
        return self._frames(tr.start(now))

    def start_next(self, now: float) -> list[Send]:
        if self.running is None and self.jobs:
            return self.start(self.jobs.popleft(), now)
        return []

    def on_response(self, data: bytes, now: float) -> tuple[list[Send], Finished | None]:
        if self.running is None:
            return [], None
        return self._step(self.running[1].on_response(data, now), now)

    def poll(self, now: float) -> tuple[list[Send], Finished | None]:
        if self.running is None:
            return [], None
        return self._step(self.running[1].poll(now), now)

    def cancel_active(self, now: float) -> SdoJob | None:
        """End the running transfer without an abort frame (the device rebooted)."""
        if self.running is None:
            return None
        job, tr = self.running
        tr.cancel(send_abort=False)
        self.running = None
        if self.jobs:
            self._ready_since = now
        return job

    def _step(self, frames: list[bytes], now: float) -> tuple[list[Send], Finished | None]:
        assert self.running is not None
        out = self._frames(frames)
        if self.running[1].done:
            finished, self.running = self.running, None
            if self.jobs:  # the next one is startable from now
                self._ready_since = now
            return out, finished
        return out, None

    def _frames(self, frames: list[bytes]) -> list[Send]:
        return [Send(COB_SDO_RX + self.node_id, f) for f in frames]
