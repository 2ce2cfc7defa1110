"""One node's SDO channel: transfers queued and run one at a time, in order (CiA 301: one
SDO server channel per node; a second request while one runs would be taken as part of it).

The channel runs ``sdo_client.SdoTransfer`` machines and tells its owner (``bus.node.Node``)
when one finishes; what a finished transfer means (a boot step, a probe, a command) is the
owner's business. No I/O, no clock: frames out, ``now`` in.

Imports: bus.sdo_client, bus.events, objref.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gateway.bus.events import Send
from gateway.bus.sdo_client import SdoTransfer
from gateway.objref import ObjRef


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
        self.active: Finished | None = None
        self._tokens = 0

    # -- queries
    @property
    def idle(self) -> bool:
        return self.active is None

    @property
    def busy(self) -> bool:
        return self.active is not None or bool(self.jobs)

    def next_deadline(self) -> float | None:
        return self.active[1].next_deadline() if self.active else None

    def find(self, purpose: str) -> SdoJob | None:
        if self.active is not None and self.active[0].purpose == purpose:
            return self.active[0]
        return next((j for j in self.jobs if j.purpose == purpose), None)

    # -- queue
    def token(self) -> int:
        self._tokens += 1
        return self._tokens

    def queue(self, obj: ObjRef, data: bytes | None, purpose: str, arg: Any = None) -> int:
        token = self.token()
        self.jobs.append(SdoJob(token, obj, data, purpose, arg))
        return token

    def drop(self, keep: Callable[[SdoJob], bool]) -> None:
        self.jobs = deque(j for j in self.jobs if keep(j))

    # -- transfers
    def start(self, job: SdoJob, now: float) -> list[Send]:
        assert self.active is None
        tr = SdoTransfer(
            job.obj.index, job.obj.sub, job.data, timeout_s=self.timeout_s, retries=self.retries
        )
        self.active = (job, tr)
        return self._frames(tr.start(now))

    def start_next(self, now: float) -> list[Send]:
        if self.active is None and self.jobs:
            return self.start(self.jobs.popleft(), now)
        return []

    def on_response(self, data: bytes, now: float) -> tuple[list[Send], Finished | None]:
        if self.active is None:
            return [], None
        return self._step(self.active[1].on_response(data, now))

    def poll(self, now: float) -> tuple[list[Send], Finished | None]:
        if self.active is None:
            return [], None
        return self._step(self.active[1].poll(now))

    def cancel_active(self) -> SdoJob | None:
        """End the running transfer without an abort frame (the device rebooted)."""
        if self.active is None:
            return None
        job, tr = self.active
        tr.cancel(send_abort=False)
        self.active = None
        return job

    def _step(self, frames: list[bytes]) -> tuple[list[Send], Finished | None]:
        assert self.active is not None
        out = self._frames(frames)
        if self.active[1].done:
            finished, self.active = self.active, None
            return out, finished
        return out, None

    def _frames(self, frames: list[bytes]) -> list[Send]:
        return [Send(0x600 + self.node_id, f) for f in frames]
