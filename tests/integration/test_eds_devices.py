"""Devices known only from their EDS, against an independent device stack: python canopen's
LocalNode built from the same EDS answers SDO (and produces its heartbeat) on a virtual bus; the
test sends the boot-up and the TPDOs itself. Values over Modbus (pymodbus) and Zenoh with the
EDS types, a config remap seen on the bus frame by frame in CiA 301 order, and a device holding
another mapping than the EDS detected by verify_mapping (values bad, Modbus 0x0B), and the
identity check against devices with less of 1018h than four sub-indices (only 1018h:01 is
mandatory, CiA 301 7.5.2.20)."""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import can
import canopen
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from canopen_gateway.image import Quality
from tests.helpers import gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient

DATA = Path(__file__).resolve().parents[1] / "data" / "eds"
IO = DATA / "io401.eds"
FLOW = DATA / "measure.eds"
P = "canopen/test"


class SdoLog(can.Listener):
    """Every SDO download request to one node, as (index, sub, value), in bus order."""

    def __init__(self, node_id: int) -> None:
        self.cob = 0x600 + node_id
        self.writes: list[tuple[int, int, int]] = []
        self.frames: list[tuple[int, bytes]] = []

    def on_message_received(self, msg: can.Message) -> None:
        self.frames.append((msg.arbitration_id, bytes(msg.data)))
        d = msg.data
        if msg.arbitration_id != self.cob or len(d) < 8 or d[0] >> 5 != 1 or not d[0] & 0x02:
            return
        size = 4 - ((d[0] >> 2) & 0x3) if d[0] & 0x01 else 4
        value = int.from_bytes(bytes(d[4 : 4 + size]), "little")
        self.writes.append((int.from_bytes(bytes(d[1:3]), "little"), d[3], value))


def local_node(eds: Path, node_id: int, channel: str) -> tuple[canopen.Network, canopen.LocalNode]:
    with eds.open(encoding="utf-8") as fp:
        od = canopen.import_od(fp, node_id)
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(node_id, od)
    net.add_node(node)
    return net, node


_STATE = {"INITIALISING": 0x00, "PRE-OPERATIONAL": 0x7F, "OPERATIONAL": 0x05, "STOPPED": 0x04}


class Heartbeat(threading.Thread):
    """The device's heartbeat sent by the test (state from the LocalNode's NMT slave)."""

    def __init__(self, bus: can.BusABC, node: canopen.LocalNode) -> None:
        super().__init__(daemon=True)
        self.bus, self.node, self.stop = bus, node, threading.Event()

    def run(self) -> None:
        while not self.stop.wait(0.05):
            state = _STATE.get(self.node.nmt.state, 0x7F)
            msg = can.Message(arbitration_id=0x700 + self.node.id, data=[state], is_extended_id=False)
            self.bus.send(msg)


def boot(node: canopen.LocalNode) -> None:
    """Power-on as CiA 301 7.3.2: boot-up 0x700+id [00], then PRE-OPERATIONAL."""
    node.nmt.send_command(0x81)  # INITIALISING: the LocalNode sends the boot-up frame
    node.nmt.send_command(0x80)


@asynccontextmanager
async def gateway_with(
    eds: Path, node_id: int, name: str, node_extra: dict[str, Any] | None = None,
    device_od: dict[tuple[int, int], int] | None = None,
    device_setup: Callable[[canopen.LocalNode], None] | None = None,
    sections: dict[str, Any] | None = None,
) -> AsyncIterator[tuple[Gateway, canopen.LocalNode, can.BusABC, SdoLog]]:  # fmt: skip
    cfg = make_config(
        # heartbeat 300 ms: the LocalNode's heartbeat is a python-can software timer
        [{"name": name, "node_id": node_id, "eds": str(eds), "heartbeat_ms": 300, **(node_extra or {})}],
        **{"simulate": {"nodes": []}, "master": {"probe_at_start": False}, **(sections or {})},
    )
    net, node = local_node(eds, node_id, cfg.can.channel)
    for (index, sub), value in (device_od or {}).items():
        var = node.sdo[index] if sub == 0 and isinstance(node.object_dictionary[index], canopen.objectdictionary.ODVariable) else node.sdo[index][sub]  # fmt: skip
        node.set_data(index, sub, var.od.encode_raw(value))
    if device_setup is not None:
        device_setup(node)
    sniffer = can.Bus(interface="virtual", channel=cfg.can.channel)
    log = SdoLog(node_id)
    notifier = can.Notifier(sniffer, [log])
    gw = gateway_of(cfg)
    await gw.start()
    hb = Heartbeat(sniffer, node)
    try:
        boot(node)
        hb.start()
        await wait_until(
            lambda: gw.master.nodes[name].lifecycle.state == "operational"
            and gw.image.nodes[name].operational(),
            8,
            f"{name} configured and operational",
        )
        yield gw, node, sniffer, log
    finally:
        hb.stop.set()
        if hb.is_alive():
            hb.join()
        await gw.stop()
        notifier.stop()
        sniffer.shutdown()
        node.nmt.stop_heartbeat()
        net.disconnect()


async def test_io_module_from_its_eds_alone_serves_its_pdo_values_over_modbus_and_zenoh() -> None:
    async with gateway_with(IO, 5, "io") as (gw, _node, bus, log):
        rt = gw.master.nodes["io"]
        # verify_mapping (on for EDS-only nodes) read 1800h../1A00h../1400h../1600h.. back
        await wait_until(lambda: gw.image.nodes["io"].is_valid("read_input_1h_to_8h"), 5, "mapping verified")
        assert rt.mapping_mismatches == []
        # TPDO1 (CiA 401 6000h:01/02 8 bit, 6100h:01 16 bit), TPDO2 (6100h:02, 6401h:01 INTEGER16)
        bus.send(can.Message(arbitration_id=0x185, data=bytes([0xA5, 0x01, 0x34, 0x12]), is_extended_id=False))  # fmt: skip
        bus.send(can.Message(arbitration_id=0x285, data=struct.pack("<Hh", 0xBEEF, -300), is_extended_id=False))  # fmt: skip
        sigs = gw.image.nodes["io"].signals
        await wait_until(lambda: sigs["analogue_input_1"].seq > 0 and sigs["read_input_1h_to_10h"].seq > 0, 5, "both TPDOs decoded")  # fmt: skip
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            regs = (await client.read_input_registers(100, count=5, device_id=5)).registers
            assert regs[:4] == [0xA5, 0x01, 0x1234, 0xBEEF]
            assert struct.unpack(">h", struct.pack(">H", regs[4]))[0] == -300
            quality = (await client.read_input_registers(0, count=1, device_id=5)).registers
            assert quality == [int(Quality.GOOD)]
            # RPDO2 (6300h:01, 6411h:01 INTEGER16) by a holding register write
            await client.write_register(103, 0xFF9C, device_id=5)  # -100
            await wait_until(lambda: (0x305, bytes.fromhex("00009CFF")) in log.frames, 5, "RPDO2 on the bus")  # fmt: skip
        finally:
            client.close()
        z = ZClient(gw.cfg.zenoh.listen)
        try:
            r = await z.get_one(f"{P}/io/value/analogue_input_1")
            assert r.ok and r.body["value"] == -300 and r.body["quality"] == "good"
            r = await z.get_one(f"{P}/io/value/read_input_1h_to_8h")
            assert r.body["value"] == 0xA5
        finally:
            z.close()


async def test_measuring_device_real32_values_and_utf8_name() -> None:
    async with gateway_with(FLOW, 6, "flow") as (gw, _node, bus, _):
        bus.send(can.Message(arbitration_id=0x186, data=struct.pack("<ff", 21.5, -3.25), is_extended_id=False))  # fmt: skip
        sigs = gw.image.nodes["flow"].signals
        await wait_until(lambda: sigs["temperatur"].seq > 0 and gw.image.nodes["flow"].is_valid("temperatur"), 5, "TPDO1 decoded, mapping verified")  # fmt: skip
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            regs = (await client.read_input_registers(100, count=4, device_id=6)).registers
        finally:
            client.close()
        assert struct.unpack(">ff", struct.pack(">HHHH", *regs)) == (21.5, -3.25)
        z = ZClient(gw.cfg.zenoh.listen)
        try:
            r = await z.get_one(f"{P}/flow/value/durchfluss")
            assert r.body["value"] == -3.25 and isinstance(r.body["value"], float)
            cat = await z.get_one(f"{P}/catalog")
            assert cat.body["nodes"]["flow"]["signals"]["zahler"]["type"] == "uint32"
        finally:
            z.close()


async def test_config_remap_goes_out_in_cia301_order_and_the_new_layout_is_decoded() -> None:
    extra = {"tpdo": {1: {"mapping": ["0x6401:01", "0x6000:01"], "transmission": 254, "event_timer_ms": 50}}}  # fmt: skip
    async with gateway_with(IO, 5, "io", extra) as (gw, _node, bus, log):
        pdo_writes = [w for w in log.writes if 0x1800 <= w[0] < 0x1C00]
        assert pdo_writes == [
            (0x1800, 1, 0x80000185),  # PDO not valid (bit 31)
            (0x1800, 2, 254),  # transmission type
            (0x1800, 5, 50),  # event timer
            (0x1A00, 0, 0),  # mapping off
            (0x1A00, 1, 0x64010110),  # 6401h:01, 16 bit
            (0x1A00, 2, 0x60000108),  # 6000h:01, 8 bit
            (0x1A00, 0, 2),  # mapping on, 2 entries
            (0x1800, 1, 0x185),  # PDO valid
        ]
        rt = gw.master.nodes["io"]
        await wait_until(lambda: gw.image.nodes["io"].is_valid("analogue_input_1") and not rt.mapping_mismatches, 5, "remap verified")  # fmt: skip
        bus.send(can.Message(arbitration_id=0x185, data=struct.pack("<hB", -7, 0x3C), is_extended_id=False))  # fmt: skip
        sigs = gw.image.nodes["io"].signals
        await wait_until(lambda: sigs["read_input_1h_to_8h"].value == 0x3C, 5, "remapped TPDO1 decoded")
        assert sigs["analogue_input_1"].value == -7


async def test_device_holding_another_mapping_than_the_eds_is_detected_and_its_values_refused() -> None:
    # the device was remapped by someone else: TPDO1 holds 6100h:01 first
    held = {(0x1A00, 1): 0x61000110, (0x1A00, 2): 0x60000108, (0x1A00, 3): 0x60000208}
    async with gateway_with(IO, 5, "io", device_od=held) as (gw, _node, bus, _):
        rt = gw.master.nodes["io"]
        await wait_until(lambda: bool(rt.mapping_mismatches), 5, "mismatch found")
        text = str(rt.mapping_mismatches[0])
        assert text.startswith("TPDO1: expected COB-ID 0x185, [0x6000:01/8, 0x6000:02/8, 0x6100:01/16]")
        assert "device holds COB-ID 0x185, [0x6100:01/16, 0x6000:01/8, 0x6000:02/8]" in text
        assert "TPDO1" in gw.image.nodes["io"].health.last_error
        await wait_until(lambda: gw.image.nodes["io"].operational(), 5, "io operational")
        bus.send(can.Message(arbitration_id=0x185, data=bytes([1, 2, 3, 4]), is_extended_id=False))
        io = gw.image.nodes["io"]
        await wait_until(lambda: io.signals["read_input_1h_to_8h"].seq > 0, 5, "frame received")
        assert io.quality(io.signals["read_input_1h_to_8h"]) == Quality.BAD
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
        await client.connect()
        try:
            rr = await client.read_input_registers(100, count=1, device_id=5)
        finally:
            client.close()
        assert rr.isError() and rr.exception_code == 0x0B


async def test_simulated_eds_only_node_runs_with_the_gateway() -> None:
    cfg = make_config([{"name": "io", "node_id": 5, "eds": str(IO)}], zenoh={"enabled": False})
    gw = gateway_of(cfg)
    await gw.start()
    try:
        sigs = gw.image.nodes["io"].signals
        await wait_until(
            lambda: gw.image.nodes["io"].operational()
            and gw.image.nodes["io"].quality(sigs["analogue_input_1"]) == Quality.GOOD,
            8,
            "simulated io node verified and sending",
        )
        assert gw.master.nodes["io"].mapping_mismatches == []
    finally:
        await gw.stop()


def _identity_uploads(log: SdoLog) -> list[int]:
    """The sub-indices of 1018h the gateway asked for (SDO initiate upload), in order."""
    return [d[3] for cob, d in log.frames if cob == log.cob and d[0] == 0x40 and d[1:3] == b"\x18\x10"]  # fmt: skip


async def test_a_device_whose_eds_defines_only_the_vendor_id_of_1018h_is_configured(
    tmp_path: Path,
) -> None:
    """The EDS gives VendorNumber and ProductNumber, but its 1018h has sub-index 01h only (as
    the device): the vendor id is compared, the product code is not asked for."""
    text = IO.read_text(encoding="utf-8")
    head, rest = text.split("[1018sub2]", 1)
    rest = rest[rest.index("[1400]") :]
    head = head.replace("SubNumber=5", "SubNumber=2").replace(
        "ParameterName=Number of entries\nObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=4",
        "ParameterName=Number of entries\nObjectType=0x7\nDataType=0x0005\nAccessType=ro\nDefaultValue=1",
    )
    eds = tmp_path / "io401-vendor-only.eds"
    eds.write_text(head + rest, encoding="utf-8")
    async with gateway_with(eds, 5, "io") as (gw, _node, _bus, log):
        assert _identity_uploads(log) == [0x01]
        assert "wrong device" not in gw.image.nodes["io"].health.last_error


def _no_1018_beyond_the_vendor_id(node: canopen.LocalNode) -> None:
    """The device answers 1018h:02..04 with "object does not exist" (SDO abort 0602 0000h)."""

    def read(index: int, subindex: int, od: object) -> None:
        if index == 0x1018 and subindex > 1:
            raise canopen.SdoAbortedError(0x06020000)

    node.add_read_callback(read)


async def test_identity_objects_the_device_says_do_not_exist_are_not_compared_said_once(
    caplog: Any,
) -> None:
    caplog.set_level(logging.INFO, logger="gateway")
    async with gateway_with(IO, 5, "io", device_setup=_no_1018_beyond_the_vendor_id) as (gw, node, _bus, log):  # fmt: skip
        assert _identity_uploads(log) == [0x01, 0x02]
        health = gw.image.nodes["io"].health
        assert "wrong device" not in health.last_error
        # a reboot: checked again, configured again, not said again
        boot(node)
        await wait_until(
            lambda: health.boot_count == 2
            and gw.master.nodes["io"].lifecycle.state == "operational"
            and gw.image.nodes["io"].operational(),
            8,
            "io configured again after its second boot-up",
        )
        assert _identity_uploads(log) == [0x01, 0x02] * 2
    said = [r.getMessage() for r in caplog.records if "not compared" in r.getMessage()]
    assert said == [
        "node io: 0x1018:02 (product) not compared: the device says 0x06020000 "
        "(Object does not exist in the object dictionary)"
    ]
