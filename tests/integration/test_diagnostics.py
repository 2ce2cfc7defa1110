"""Every documented metric (docs/deploy.md section 6) and every node diagnostics register
(docs/modbus.md IR 0-15, gateway unit 247) is made to count here, through a real Modbus client
and a real HTTP scrape, with frames sent by the test and a simulated SGH10."""

from __future__ import annotations

import logging
import random
import struct
from typing import Any

import can
from prometheus_client.parser import text_string_to_metric_families
from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from tests.helpers import frame, free_port, gateway_of, make_config, node_operational, wait_until
from tests.integration.test_health_http import http_get

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}


async def scrape(gw: Gateway) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    _, _, body = await http_get(f"http://127.0.0.1:{gw.health.port}/metrics")
    out = {}
    for fam in text_string_to_metric_families(body.decode()):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def metric(m: dict, name: str, **labels: str) -> float:
    return m.get(("canopen_gateway_" + name, tuple(sorted(labels.items()))), 0.0)


async def test_every_documented_metric_and_diagnostics_register_counts() -> None:
    cfg = make_config([WIRE], health={"port": free_port()}, zenoh={"enabled": True})
    gw = gateway_of(cfg)
    await gw.start()
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port)
    try:
        await client.connect()
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        img = gw.image.nodes["wire"]
        sim = gw.sim.nodes["wire"]
        assert img.health.boot_count == 0  # found running by the probe
        gw.sim.runner.call(lambda now: sim.power_cycle(now))  # the runner sends the boot-up
        await wait_until(lambda: img.health.boot_count == 1, 3, "boot-up seen")
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational again")
        # process data flows: frames in/out, data age, quality good (a TPDO after NMT start)
        seq = img.signals["position"].seq
        await wait_until(lambda: img.signals["position"].seq > seq + 2, 3, "TPDOs")
        diag = (await client.read_input_registers(0, count=16, device_id=1)).registers
        assert diag[0] == 0 and diag[1] == 5 and diag[2] == 1 and diag[3] == 3
        assert (diag[4] << 16 | diag[5]) < 0xFFFFFFFF  # data age known
        assert diag[14] == 1  # boot_count

        # a short PDO, a long PDO, a short EMCY: IR 15 and decode_errors_total{reason}
        bus.send(frame(0x181, b"\x01\x02"))
        bus.send(frame(0x181, struct.pack("<ih", 5, 1) + b"\xee\xee"))
        bus.send(frame(0x081, b"\x05"))
        # an EMCY the device raises: emcy_total, IR 6-8, error_active bit
        gw.sim.runner.call(lambda now: sim.raise_emcy(0xFF05, 0x81, now=now))
        await wait_until(lambda: img.health.emcy_count == 1, 3, "EMCY counted")
        await wait_until(
            lambda: img.rx.pdo_too_long == 1 and img.health.emcy_errors == 1, 3, "bad frames"
        )
        diag = (await client.read_input_registers(0, count=16, device_id=1)).registers
        assert (diag[6], diag[7], diag[8]) == (0xFF05, 0x81, 1)
        assert diag[15] == 2, "one short and one long PDO (EMCY counted apart)"
        bits = await client.read_discrete_inputs(0, count=4, device_id=1)
        assert bits.bits[:4] == [True, True, True, True]  # alive, operational, link ok, error

        # an SDO abort: IR 12-13 and sdo_aborts_total; a read: sdo_requests_total + latency
        assert (await client.read_holding_registers(100, count=1, device_id=1)).isError() is False
        try:
            await gw.commands.sdo_read("wire", "0x6FFF:00")
        except Exception:  # noqa: BLE001 - the abort is what we want
            pass
        diag = (await client.read_input_registers(12, count=2, device_id=1)).registers
        assert diag == [0x0602, 0x0000]

        # unknown COB-IDs and an error frame: gateway unit 247
        bus.send(frame(0x3F0, b"\x00"))
        bus.send(can.Message(arbitration_id=0x04, data=bytes([0, 0x40]), is_error_frame=True))
        await wait_until(lambda: gw.image.counters["unknown_cob_id"] == 1, 3, "unknown COB-ID")
        await wait_until(lambda: gw.image.counters["bus_errors"] >= 1, 3, "error frame")
        g = (await client.read_input_registers(0, count=19, device_id=247)).registers
        u32 = lambda i: g[i] << 16 | g[i + 1]  # noqa: E731
        assert g[0] == 1 and u32(1) > 0 and u32(3) > 0
        assert u32(5) == 1, "decode_errors: the short PDO"
        assert u32(7) == 1 and u32(9) >= 1
        assert g[16:19] == [1, 1, 1]

        # a Modbus exception
        assert (await client.read_input_registers(9000, count=1, device_id=1)).isError()

        m = await scrape(gw)
        assert metric(m, "frames_in_total") > 0 and metric(m, "frames_out_total") > 0
        assert metric(m, "bus_errors_total") >= 1
        assert metric(m, "decode_errors_total", node="wire", reason="short") == 1
        assert metric(m, "decode_errors_total", node="wire", reason="too_long") == 1
        assert metric(m, "decode_errors_total", node="wire", reason="emcy_short") == 1
        assert metric(m, "emcy_total", node="wire") == 1
        assert metric(m, "sdo_requests_total", node="wire", op="read") >= 2
        assert metric(m, "sdo_aborts_total", node="wire", code="0x06020000") == 1
        assert metric(m, "sdo_latency_seconds_count", node="wire") >= 2
        assert metric(m, "modbus_requests_total", function="read_input_registers") >= 4
        assert metric(m, "modbus_exceptions_total", code="0x02") >= 1
        assert metric(m, "zenoh_publications_total") > 0
        assert metric(m, "node_nmt_state", node="wire") == 5
        assert metric(m, "node_alive", node="wire") == 1
        assert metric(m, "node_data_age_seconds", node="wire") < 60
        assert metric(m, "uptime_seconds") >= 0

        # silence: loss counted (IR 9), NMT unknown (IR 1 = 65535), stale (IR 0 = 1)
        losses = img.health.loss_count  # 0, unless a starved machine already lost it once
        gw.sim.runner.call(lambda now: sim.silence())
        await wait_until(lambda: not img.health.alive, 3, "wire lost")
        diag = (await client.read_input_registers(0, count=10, device_id=1)).registers
        assert diag[0] == 1 and diag[1] == 0xFFFF and diag[2] == 0 and diag[9] == losses + 1
        m = await scrape(gw)
        assert metric(m, "node_alive", node="wire") == 0
        assert metric(m, "node_nmt_state", node="wire") == -1
    finally:
        client.close()
        bus.shutdown()
        await gw.stop()


async def test_random_29_bit_traffic_is_logged_as_a_few_summary_lines(caplog: Any) -> None:
    cfg = make_config([WIRE], modbus={"enabled": False}, zenoh={"enabled": False})
    gw = gateway_of(cfg)
    await gw.start()
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    rnd = random.Random(7)
    try:
        await wait_until(lambda: node_operational(gw, "wire"), 5, "wire operational")
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            before = gw.image.counters["unknown_cob_id"]
            for _ in range(5000):
                bus.send(
                    can.Message(
                        arbitration_id=rnd.getrandbits(29),
                        data=rnd.randbytes(rnd.randint(0, 8)),
                        is_extended_id=True,
                    )
                )
            # each of the 5000 is counted as an unknown COB-ID: then all were processed
            await wait_until(
                lambda: gw.image.counters["unknown_cob_id"] - before == 5000, 5, "all processed"
            )
        lines = [r for r in caplog.records if "COB-ID" in r.getMessage()]
        assert 1 <= len(lines) <= 2, [r.getMessage() for r in lines]
        assert node_operational(gw, "wire"), "a 29-bit frame is never taken for a PDO"
    finally:
        bus.shutdown()
        await gw.stop()
