"""The audit's records (commands.audit): a write that may have reached a device is recorded
whatever ends it (done, an error, its client's cancellation: ``unknown``) and its caller waits
for the record to be on disk; the record names who the adapter authenticated and keeps what
the client said of itself as a marked hint; refused writes are recorded without waiting and at
most once per client, operation and reason in a period."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from canopen_gateway.commands.audit import RefusalAudit, acting_as, audited
from canopen_gateway.errors import SdoAbort


class Disk:
    """A sink whose records are on disk when the test says so."""

    def __init__(self) -> None:
        self.records: list[dict[str, Any]] = []
        self.pending: list[asyncio.Future[None]] = []

    def __call__(self, record: dict[str, Any]) -> asyncio.Future[None]:
        self.records.append(record)
        fut = asyncio.get_running_loop().create_future()
        self.pending.append(fut)
        return fut

    def commit(self) -> None:
        for fut in self.pending:
            if not fut.done():
                fut.set_result(None)


class Service:
    def __init__(self, sink: Any) -> None:
        self.audit = sink
        self.gate = asyncio.Event()

    @audited("sdo_write", lambda _svc, node, obj, value: (node, obj, value, value.to_bytes(2, "little", signed=True)))
    async def sdo_write(self, node: str, obj: str, value: int) -> None:
        if value < 0:
            raise SdoAbort(0x06090030, "value range of parameter exceeded")
        await self.gate.wait()


async def test_a_done_write_answers_once_its_record_is_on_disk_with_who_and_the_marked_hint() -> None:
    disk = Disk()
    svc = Service(disk)
    svc.gate.set()
    with acting_as("zenoh", "zenoh session 0123"):
        write = asyncio.ensure_future(svc.sdo_write("wire", "0x6411:00", 499))
        await asyncio.sleep(0)
        await asyncio.sleep(0)
    assert not write.done()  # the record is not on disk yet
    disk.commit()
    await write
    (rec,) = disk.records
    assert rec["who"] == "zenoh" and rec["hint"] == "zenoh session 0123 (said by the client, not verified)"
    assert (rec["what"], rec["value"], rec["raw"], rec["outcome"]) == ("0x6411:00", 499, "f301", "done")


async def test_a_write_cancelled_by_its_client_is_recorded_unknown_before_the_cancellation_goes_on() -> None:
    disk = Disk()
    svc = Service(disk)
    with acting_as("ascii 127.0.0.1:5000"):
        write = asyncio.ensure_future(svc.sdo_write("wire", "0x6411:00", 7))
    await asyncio.sleep(0)
    write.cancel()
    await asyncio.sleep(0)
    (rec,) = disk.records
    assert rec["outcome"] == "unknown" and "may have taken it" in rec["detail"]
    assert rec["who"] == "ascii 127.0.0.1:5000" and "hint" not in rec
    disk.commit()
    with pytest.raises(asyncio.CancelledError):
        await write


async def test_an_aborted_write_is_recorded_with_its_abort_code() -> None:
    disk = Disk()
    disk_commit = asyncio.get_running_loop().call_soon(disk.commit)
    with acting_as("modbus 10.0.0.5 tls role Operator subject CN=plc"), pytest.raises(SdoAbort):
        await Service(disk).sdo_write("wire", "0x6411:00", -1)
    disk_commit.cancel()
    assert disk.records[0]["outcome"].startswith("abort 0x06090030: ")
    assert disk.records[0]["who"] == "modbus 10.0.0.5 tls role Operator subject CN=plc"


async def test_refusals_are_handed_over_without_waiting_and_rate_limited() -> None:
    disk = Disk()
    now = [0.0]
    refusals = RefusalAudit(lambda: disk, clock=lambda: now[0], period_s=10.0)
    with acting_as("modbus 10.0.0.9"):
        for _ in range(3):
            refusals.refused("modbus_write", "", "function 6", None, "not in allowed_networks")
        now[0] = 11.0
        refusals.refused("modbus_write", "", "function 6", None, "not in allowed_networks")
    assert [r["outcome"] for r in disk.records] == [
        "refused: not in allowed_networks",
        "refused: not in allowed_networks (2 more like it not recorded since the previous record)",
    ]
    assert all(r["who"] == "modbus 10.0.0.9" and r["value"] is None for r in disk.records)
