"""A device known only from its EDS, across processes: the gateway runs as its own process
(``canopen-gateway run``), the device is python canopen's LocalNode built from the same EDS in
the test process, and the two share a CAN bus through python-can-remote. The test sends the
boot-up, the heartbeat and the TPDOs; values arrive over Modbus (pymodbus) and Zenoh, and a
holding-register write comes back as the RPDO the EDS maps."""

from __future__ import annotations

import asyncio
import os
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import canopen
import pytest
import yaml
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.image import Quality
from tests.helpers import free_port, start_can_remote, wait_can_remote, wait_until
from tests.integration.test_eds_devices import IO, Heartbeat, boot
from tests.zenoh_client import ZClient, sample_where

pytest.importorskip("can_remote")

ROOT = Path(__file__).resolve().parents[2]


class Frames(can.Listener):
    def __init__(self) -> None:
        self.seen: list[tuple[int, bytes]] = []
        self.event = threading.Event()

    def on_message_received(self, msg: can.Message) -> None:
        self.seen.append((msg.arbitration_id, bytes(msg.data)))
        self.event.set()


async def test_eds_only_node_served_by_a_gateway_process_over_python_can_remote(
    tmp_path: Path,
) -> None:
    can_port, zenoh_port = free_port(), free_port()
    server = start_can_remote(can_port, f"eds{can_port}")
    channel = f"ws://127.0.0.1:{can_port}/"
    raw = {
        "gateway": {"name": "edsxp"},
        "can": {"interface": "remote", "channel": channel},
        "master": {"heartbeat_ms": 200, "probe_at_start": False},
        "nodes": [{"name": "io", "node_id": 5, "eds": str(IO), "heartbeat_ms": 300}],
        "modbus": {"port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{zenoh_port}"]},
    }
    cfg = tmp_path / "edsxp.yaml"
    cfg.write_text(yaml.safe_dump(raw))
    gw: subprocess.Popen[str] | None = None
    net: canopen.Network | None = None
    hb: Heartbeat | None = None
    z: ZClient | None = None
    try:
        wait_can_remote(server, can_port)
        gw = subprocess.Popen(
            [sys.executable, "-m", "canopen_gateway", "run", "-c", str(cfg)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
            cwd=ROOT,
        )
        assert gw.stdout is not None
        line = gw.stdout.readline()
        assert "canopen-gateway" in line, f"gateway did not start: {line!r}"

        with IO.open(encoding="utf-8") as fp:
            od = canopen.import_od(fp, 5)
        net = canopen.Network()
        net.connect(interface="remote", channel=channel)
        node = canopen.LocalNode(5, od)
        # the heartbeat is the test's (thread below): the LocalNode's own periodic task cannot
        # be updated through python-can-remote 0.3.0 (CyclicSendTask.modify_data raises
        # TypeError, and the remote connection does not survive it)
        node.nmt.start_heartbeat = lambda heartbeat_time_ms: None  # type: ignore[method-assign]
        net.add_node(node)
        frames = Frames()
        net.notifier.add_listener(frames)
        z = ZClient([f"tcp/127.0.0.1:{zenoh_port}"])
        tokens = z.watch_liveliness("canopen/edsxp/alive/io")
        assert net.bus is not None
        hb = Heartbeat(net.bus, node)
        boot(node)
        hb.start()
        # configured (SDO over the remote bus), started, change-only TPDOs refreshed by SDO
        await sample_where(tokens, lambda s: s.kind == "PUT", timeout_s=15, what="io token")
        assert node.nmt.state == "OPERATIONAL"

        net.bus.send(can.Message(arbitration_id=0x185, data=bytes([0x5A, 0x02, 0x78, 0x56]), is_extended_id=False))  # fmt: skip
        net.bus.send(can.Message(arbitration_id=0x285, data=struct.pack("<Hh", 0x1234, -2), is_extended_id=False))  # fmt: skip
        client = AsyncModbusTcpClient("127.0.0.1", port=raw["modbus"]["port"], timeout=3)  # type: ignore[index]
        await client.connect()
        try:

            async def inputs() -> list[int]:
                return (await client.read_input_registers(100, count=5, device_id=5)).registers

            want = [0x5A, 0x02, 0x5678, 0x1234, 0xFFFE]
            regs: list[int] = []

            async def arrived() -> bool:
                nonlocal regs
                regs = await inputs()
                return regs == want

            deadline = time.monotonic() + 10
            while not await arrived():
                assert time.monotonic() < deadline, f"TPDO values not served: {regs}"
                await asyncio.sleep(0.01)
            quality = (await client.read_input_registers(0, count=1, device_id=5)).registers
            assert quality == [int(Quality.GOOD)]
            frames.event.clear()
            await client.write_register(103, 0xFFF6, device_id=5)  # RPDO2 6411h:01 = -10
            await wait_until(lambda: (0x305, bytes.fromhex("0000F6FF")) in frames.seen, 10, "RPDO2")
            r = await z.get_one("canopen/edsxp/io/value/analogue_input_1")
            assert r.ok and r.body["value"] == -2 and r.body["quality"] == "good"

            # the device reboots: the values of its previous boot are never served as good
            boot(node)
            await sample_where(tokens, lambda s: s.kind == "DELETE", timeout_s=10, what="token gone")
            await sample_where(tokens, lambda s: s.kind == "PUT", timeout_s=15, what="token back")
            quality = (await client.read_input_registers(0, count=1, device_id=5)).registers
            assert quality != [int(Quality.GOOD)]  # started again, no TPDO since
            stale = await client.read_input_registers(100, count=5, device_id=5)
            assert stale.isError() and stale.exception_code == 0x0B
            r = await z.get_one("canopen/edsxp/io/value/analogue_input_1")
            assert r.body["quality"] != "good"
            net.bus.send(can.Message(arbitration_id=0x185, data=bytes([1, 2, 3, 4]), is_extended_id=False))  # fmt: skip
            net.bus.send(can.Message(arbitration_id=0x285, data=struct.pack("<Hh", 5, 6), is_extended_id=False))  # fmt: skip
            want = [1, 2, 0x0403, 5, 6]
            deadline = time.monotonic() + 10
            while not await arrived():
                assert time.monotonic() < deadline, f"new TPDO values not served: {regs}"
                await asyncio.sleep(0.01)
        finally:
            client.close()
    finally:
        if z is not None:
            z.close()
        if hb is not None:
            hb.stop.set()
            if hb.is_alive():
                hb.join()
        if net is not None:
            net.disconnect()
        if gw is not None:
            if gw.poll() is None:
                gw.send_signal(signal.SIGTERM)
            try:
                gw.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                gw.kill()
                gw.communicate()
        server.terminate()
        try:
            server.wait(timeout=5)
        except subprocess.TimeoutExpired:
            server.kill()
