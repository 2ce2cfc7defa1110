"""MSK5000 (manual 001: 5115h referencing, EMCY FF10h) among other encoders on one bus: when the
device loses its reference and says so by EMCY, the gateway reads 5115h at once and stops
serving the position as good (Modbus 0x0B, Zenoh quality not good), whatever the order in which
the other nodes' heartbeats arrive. The MSK5000 is python canopen's LocalNode (an SDO server
that is not ours) built from the profile's EDS; its heartbeat, boot-up, TPDO and EMCY frames
are sent by the test. Three SGH10 encoders from our simulator send heartbeats every 200 ms."""

from __future__ import annotations

import struct
import threading
from pathlib import Path

import can
import canopen
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.pdu import ExceptionResponse

from tests.helpers import gateway_of, make_config, wait_until
from tests.zenoh_client import ZClient

EDS = Path(__file__).resolve().parents[2] / "canopen_gateway" / "profiles" / "msk5000.eds"
TAPE = 37
_STATE = {"INITIALISING": 0x00, "PRE-OPERATIONAL": 0x7F, "OPERATIONAL": 0x05, "STOPPED": 0x04}


class Device(threading.Thread):
    """The tape encoder's cyclic frames: heartbeat every 200 ms and TPDO1 (6004h position,
    6030h:01 speed) every 50 ms once operational (what the device does with 1800h:05 set)."""

    def __init__(self, bus: can.BusABC, node: canopen.LocalNode) -> None:
        super().__init__(daemon=True)
        self.bus, self.node, self.stop = bus, node, threading.Event()
        self.position = 12345

    def run(self) -> None:
        tick = 0
        while not self.stop.wait(0.05):
            tick += 1
            state = _STATE.get(self.node.nmt.state, 0x7F)
            if tick % 4 == 0:
                self.bus.send(can.Message(arbitration_id=0x700 + TAPE, data=[state], is_extended_id=False))  # fmt: skip
            if state == 0x05:
                data = struct.pack("<ih", self.position, 0)
                self.bus.send(can.Message(arbitration_id=0x180 + TAPE, data=data, is_extended_id=False))  # fmt: skip


async def test_reference_lost_after_emcy_ff10_is_never_served_as_good() -> None:
    others = [{"name": f"wire{i}", "node_id": i, "profile": "sgh10", "heartbeat_ms": 200} for i in (1, 2, 3)]  # fmt: skip
    cfg = make_config(
        [*others, {"name": "tape", "node_id": TAPE, "profile": "msk5000", "heartbeat_ms": 200}],
        simulate={"nodes": ["wire1", "wire2", "wire3"]},
        master={"probe_at_start": False},
    )
    with EDS.open(encoding="utf-8") as fp:
        od = canopen.import_od(fp, TAPE)
    net = canopen.Network()
    net.connect(interface="virtual", channel=cfg.can.channel)
    node = canopen.LocalNode(TAPE, od)
    net.add_node(node)
    node.set_data(0x5115, 0, b"\x01")  # referenced
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    dev = Device(bus, node)
    gw = gateway_of(cfg)
    await gw.start()
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=3)
    z = ZClient(gw.cfg.zenoh.listen)
    tape = gw.image.nodes["tape"]
    try:
        node.nmt.send_command(0x81)  # power-on: boot-up frame, then PRE-OPERATIONAL
        node.nmt.send_command(0x80)
        dev.start()
        await wait_until(lambda: tape.operational() and tape.is_valid("position") and tape.signals["position"].seq > 0, 8, "tape referenced and sending")  # fmt: skip
        await wait_until(lambda: all(gw.image.nodes[f"wire{i}"].operational() for i in (1, 2, 3)), 8, "the other encoders operational")  # fmt: skip
        await client.connect()
        rr = await client.read_input_registers(100, count=2, device_id=TAPE)
        assert not rr.isError()
        r = await z.get_one("canopen/test/tape/value/position")
        assert r.ok and r.body["quality"] == "good"

        # the device loses its reference and says so (EMCY FF10h, error register 81h)
        node.set_data(0x5115, 0, b"\x00")
        bus.send(can.Message(arbitration_id=0x80 + TAPE, data=bytes([0x10, 0xFF, 0x81, 0, 0, 0, 0, 0]), is_extended_id=False))  # fmt: skip
        await wait_until(lambda: not tape.is_valid("position"), 5, "position marked not valid after the EMCY")  # fmt: skip
        rr = await client.read_input_registers(100, count=2, device_id=TAPE)
        assert isinstance(rr, ExceptionResponse) and rr.exception_code == 0x0B
        r = await z.get_one("canopen/test/tape/value/position")
        assert r.body["quality"] != "good"
        assert tape.signals["position"].seq > 0  # the device kept sending: still not good
    finally:
        dev.stop.set()
        if dev.is_alive():
            dev.join()
        client.close()
        z.close()
        await gw.stop()
        bus.shutdown()
        net.disconnect()
