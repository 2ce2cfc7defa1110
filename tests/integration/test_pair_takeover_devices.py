"""What the devices see across a take-over of a hot-standby pair: two in-process gateways of one
config on one virtual bus (each gateway's frames recorded at its own driver: a virtual bus
cannot say who sent a frame), the devices simulated (an AP05, manual 004) or python canopen's
LocalNode (the POSI+ EDS: an SDO server not ours). "A dies": not one more frame leaves it.

* A standby started after the PLC's writes learns every RPDO from the active gateway's frames;
  after the take-over each RPDO it sends is the one the old active gateway last sent (but the
  guarding bit, control word bit 8, AP05 manual 5.5.5), the keep-alive goes on at once, and a
  write of set point 1 sends RPDO1 with the control word bits the PLC set through A.
* A PLC that dies with the active gateway: the new one's output watchdog counts from the PLC's
  last write it heard on the bus, and writes the safe outputs without a write of its own.
* A segmented SDO download cut by A's death between two segments is aborted by B before any
  other request of B to that node.
"""

from __future__ import annotations

import asyncio
import struct
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import VISIBLE_STRING
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.canopen.objref import ObjRef
from canopen_gateway.config import parse_config
from canopen_gateway.modbus.watchdog import TIMEOUT, WatchdogState
from canopen_gateway.sim.buses import SimulatedBus
from tests.helpers import (
    free_port,
    gateway_of,
    make_config,
    node_operational,
    simulated_bus,
    wait_until,
)
from tests.integration.test_pair import Sent
from tests.integration.test_pair_localnode import pair_with_localnode
from tests.pair_invariants import left_open_aborted_first, outputs_known_alike, rpdos_resume_as_sent

LOGICAL, HB_MS = 100, 100
RPDO1, RPDO2 = 0x202, 0x302  # AP05 node 2: 200h / 300h + node id (manual 5.3.1.2 table 26)
#: the AP05 control word is bytes 6-7 of both RPDOs; its bit 8 (byte 7 bit 0) is the guarding
#: bit the gateway toggles as the device echoes it (manual 5.5.5): each gateway's own
GUARDING_BIT = {RPDO1: bytes(7) + b"\x01", RPDO2: bytes(7) + b"\x01"}
REDUNDANCY = {"priority_slot_ms": 50, "device_slot_ms": 1}  # a take-over of about 0.5 s


def pair_configs(display: dict[str, Any], **sections: Any) -> tuple[Any, Any]:
    """A (pair id 101, priority 0) and B (102, 1): an SGH10 (its heartbeat tells the standby
    the bus is alive) and the AP05 ``display`` at node id 2 (with these keys more)."""
    base = make_config(
        [
            {"name": "wire", "node_id": 1, "profile": "sgh10", "heartbeat_ms": 100},
            {"name": "display", "node_id": 2, "profile": "ap05", "heartbeat_ms": 100, **display},
        ],
        master={"node_id": LOGICAL, "heartbeat_ms": HB_MS, "sync_period_ms": 0},
        zenoh={"enabled": False},
        **sections,
    )
    raw = base.model_dump(exclude_none=True)
    raw["simulate"] = {"nodes": []}

    def member(node_id: int, priority: int) -> Any:
        red = {**REDUNDANCY, "node_id": node_id, "priority": priority}
        modbus = {**raw["modbus"], "port": free_port()}
        return parse_config({**raw, "master": {**raw["master"], "redundancy": red}, "modbus": modbus}, environ={})

    return member(101, 0), member(102, 1)


@asynccontextmanager
async def active_a(cfgs: tuple[Any, Any]) -> AsyncIterator[tuple[Gateway, Gateway, Sent, Sent, SimulatedBus]]:
    """A started and the devices configured; B built, not started (the test starts it)."""
    cfg_a, cfg_b = cfgs
    sim = simulated_bus(cfg_a, names=["wire", "display"])
    a, b = gateway_of(cfg_a, simulate=False), gateway_of(cfg_b, simulate=False)
    sent_a, sent_b = Sent(a), Sent(b)
    try:
        await a.start()
        # the devices power on once A listens: their boot-ups are the first frames it hears (on a
        # bus silent from its start a first master waits 2 s before it claims the bus)
        sim.start()
        for name in ("wire", "display"):
            await wait_until(lambda n=name: node_operational(a, n), 10, f"A configures {name}")
        yield a, b, sent_a, sent_b, sim
    finally:
        await b.stop()
        await a.stop()
        sim.stop()


def kill(a: Gateway, sent_a: Sent) -> None:
    """A dies: not one more frame, and it does nothing more of its own."""
    sent_a.silent = True
    a.master.mastering = False


def rpdos(sent: Sent, since: int = 0) -> list[tuple[int, bytes]]:
    return [(c, d) for c, d in sent.frames[since:] if c in (RPDO1, RPDO2)]


async def test_a_standby_started_after_the_plcs_writes_sends_every_rpdo_as_the_old_active_one_last_did() -> None:
    cfgs = pair_configs({"guarding_bit": {"period_ms": 100}})  # a keep-alive every 100 ms
    async with active_a(cfgs) as (a, b, sent_a, sent_b, sim):
        # the PLC's writes through A (the command service, as Modbus and Zenoh write)
        await a.commands.write_signals("display", {"set_point1": 1000, "control_word": 0x0004})
        await a.commands.write_signals("display", {"set_point2": 2000, "control_word": 0x0304})
        await b.start()  # after the writes: it hears the keep-alives only
        out_a, out_b = a.master.nodes["display"].node.outputs, b.master.nodes["display"].node.outputs
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        await wait_until(lambda: not out_b.unknown, 5, "B heard every RPDO (the keep-alive round)")
        assert outputs_known_alike(out_a, out_b) == []
        assert b.image.nodes["display"].output("set_point1") == 1000  # as on A, not 0

        kill(a, sent_a)
        taken = len(sent_b.frames)
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        await wait_until(lambda: {c for c, _ in rpdos(sent_b, taken)} == {RPDO1, RPDO2}, 5, "B's keep-alive round")
        assert rpdos_resume_as_sent(rpdos(sent_a), rpdos(sent_b, taken), GUARDING_BIT) == []
        # the keep-alive went on at once: right after B's first logical heartbeat
        after = [c for c, _ in sent_b.frames[taken:] if c in (RPDO1, RPDO2, 0x700 + LOGICAL)]
        assert after[0] == 0x700 + LOGICAL and after[1] in (RPDO1, RPDO2), after[:4]

        # a write of set point 1 through B: RPDO1 with the control word the PLC set through A
        mark = len(sent_b.frames)
        await b.commands.write_signals("display", {"set_point1": 1111})
        (data,) = [d for c, d in rpdos(sent_b, mark) if c == RPDO1][:1]
        set_point1, control = struct.unpack_from("<i", data)[0], int.from_bytes(data[6:8], "little")
        assert (set_point1, control & ~0x0100) == (1111, 0x0304 & ~0x0100)
        device = sim.nodes["display"]
        await wait_until(lambda: device.get(0x5F16, 3) == 1111, 5, "the device has set point 1")
        assert device.get(0x5F16, 1) == 2000 and device.get(0x5F0C, 0) & ~0x0100 == 0x0304 & ~0x0100
        # and no NMT command from B: the AP05 was adopted as it ran
        assert [c for c, _ in sent_b.frames if c == 0x000] == []


async def test_a_plc_that_dies_with_the_active_gateway_gets_the_safe_outputs_from_the_new_one() -> None:
    cfgs = pair_configs(
        {"safe_outputs": {"set_point2": 0}}, modbus={"watchdog_ms": 300}
    )
    async with active_a(cfgs) as (a, b, sent_a, sent_b, sim):
        await b.start()
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        outputs = b.master.nodes["display"].node.outputs
        await wait_until(lambda: not outputs.unknown, 5, "B heard every RPDO once (a keep-alive round)")
        assert a.modbus is not None and b.modbus is not None
        point = next(p for p in a.modbus.regmap.points if (p.node, p.name) == ("display", "set_point2"))
        plc = AsyncModbusTcpClient("127.0.0.1", port=a.modbus.port, timeout=3)
        await plc.connect()
        try:
            words = list(struct.unpack(">HH", struct.pack(">i", 4321)))
            rr = await plc.write_registers(point.address, words, device_id=point.unit)
            assert not rr.isError(), rr
        finally:
            plc.close()  # the PLC dies with A
        record = b.image.nodes["display"]
        await wait_until(lambda: record.output("set_point2") == 4321, 5, "B heard the write")
        heard_s = record.outputs.monotonic
        assert b.modbus.watchdog.state is WatchdogState.STANDBY

        kill(a, sent_a)
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        wd = b.modbus.watchdog
        await wait_until(lambda: wd.trips[TIMEOUT] == 1, 5, "B's watchdog trips without a write of its own")
        assert wd.last_request_s == heard_s  # counted from the PLC's write heard on the bus
        await wait_until(lambda: record.health.outputs == "safe", 5, "B wrote the safe outputs")
        (data,) = [d for c, d in rpdos(sent_b) if c == RPDO2][-1:]
        assert struct.unpack_from("<i", data)[0] == 0
        await wait_until(lambda: sim.nodes["display"].get(0x5F16, 1) == 0, 5, "the device has the safe value")


TEXT = ObjRef(0x2000, 0x00)  # a VISIBLE_STRING the test adds to the LocalNode's dictionary


async def test_a_segmented_download_cut_by_the_active_ones_death_is_aborted_by_the_new_one_first() -> None:
    async with pair_with_localnode() as (a, b, sent_a, sent_b, node, heard):
        var = ODVariable("text", TEXT.index, TEXT.sub)
        var.data_type, var.access_type = VISIBLE_STRING, "rw"
        node.object_dictionary.add_object(var)
        await wait_until(lambda: b.master.role == "standby", 5, "B standby")
        # A dies right after its first segment: the device answers it, and waits for the next
        real = a.driver.send

        def first_segment_then_dead(cob_id: int, data: bytes, **kw: Any) -> None:
            real(cob_id, data, **kw)
            if cob_id == 0x603 and data[0] >> 5 == 0:  # a download segment (ccs 0)
                sent_a.silent = True
                a.master.mastering = False

        a.driver.send = first_segment_then_dead  # type: ignore[method-assign]
        write = asyncio.ensure_future(a.master.sdo("enc", TEXT, b"ABCDEFGHIJKLMNOPQRSTUVWXYZ"))
        await wait_until(lambda: sent_a.silent, 5, "A's first segment went out")
        await wait_until(
            lambda: [d[0] >> 5 for _, d in heard.sdo_requests].count(0) == 1, 5,
            "the device heard the first segment",
        )  # fmt: skip
        since = len(heard.sdo_requests)
        taken = len(sent_b.frames)
        await wait_until(lambda: b.master.role == "active", 5, "B takes over")
        await wait_until(lambda: any(c == 0x603 for c, _ in sent_b.frames[taken:]), 5, "B's abort")
        assert left_open_aborted_first([("B", f) for f in sent_b.frames[taken:]], 3, "B") == []
        abort = next(d for c, d in sent_b.frames[taken:] if c == 0x603)
        assert abort == bytes((0x80, 0x00, 0x20, 0x00, 0x00, 0x00, 0x04, 0x05))  # 2000h:00, 05040000h
        await wait_until(lambda: len(heard.sdo_requests) > since, 5, "the device heard the abort")
        assert [d for _, d in heard.sdo_requests[since:]] == [abort]  # the device got it, once
        write.cancel()
