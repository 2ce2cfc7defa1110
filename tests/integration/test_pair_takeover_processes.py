"""The standby's outputs across a take-over on real processes: two gateway processes and the
simulated devices (an AP05 at node id 2, manual 004) on the attributed socketcand relay
(tests/pair_bus.py, the plant of tests/integration/test_pair_faults.py), a PLC writing over
Modbus TCP.

The PLC writes set point 1 and the control word through A; B starts after those writes and,
standing by, serves set point 1 as A sent it (it hears every RPDO in A's keep-alive round). A is
killed (SIGKILL): every RPDO B sends is the one A last sent (the guarding bit aside), and a
write of set point 1 through B keeps the control word bits the PLC set through A.
"""

from __future__ import annotations

import os
import struct
import subprocess
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from canopen_gateway.config import load_config
from canopen_gateway.northbound.regmap import Point, build_register_map
from tests.helpers import stop_process, wait_until_sync, with_nodes
from tests.integration.test_pair_faults import (
    A_ID,
    B_ID,
    COB_NMT,
    Member,
    gateway_argv,
    kill,
    node_detail,
    nodes_alive,
    start_member,
    wait_role,
    write_config,
)
from tests.pair_bus import PairBus
from tests.pair_invariants import rpdos_resume_as_sent

RPDO1, RPDO2 = 0x202, 0x302  # AP05 node 2 (manual 5.3.1.2 table 26)
GUARDING_BIT = {RPDO1: bytes(7) + b"\x01", RPDO2: bytes(7) + b"\x01"}  # control word bit 8
ROOT = Path(__file__).resolve().parents[2]


def points(cfg: Path) -> dict[str, Point]:
    rm = build_register_map(*with_nodes(load_config(cfg, environ={})))
    return {p.name: p for p in rm.node_points("display") if p.table == "hr"}


def write(m: Member, p: Point, value: int) -> None:
    words = list(struct.unpack(">HH", struct.pack(">i", value))) if p.count == 2 else [value]
    with ModbusTcpClient("127.0.0.1", port=m.modbus_port, timeout=5) as plc:
        assert plc.connect()
        r = plc.write_registers(p.address, words, device_id=p.unit)
        assert not r.isError(), (p.name, value, getattr(r, "exception_code", r))


def read(m: Member, p: Point) -> int | None:
    with ModbusTcpClient("127.0.0.1", port=m.modbus_port, timeout=5) as client:
        assert client.connect()
        r = client.read_holding_registers(p.address, count=p.count, device_id=p.unit)
        if r.isError():
            return None
        raw = struct.pack(">" + "H" * p.count, *r.registers)
        return int(struct.unpack(">i", raw)[0]) if p.count == 2 else int(r.registers[0])


def test_a_standby_started_after_the_plcs_writes_serves_them_and_sends_them_on_after_a_kill(tmp_path: Path) -> None:
    with ExitStack() as stack:
        bus = stack.enter_context(PairBus())
        cfg = write_config(tmp_path, bus)
        p = points(cfg)
        a = start_member(tmp_path, cfg, "A", A_ID, 0, B_ID)
        stack.callback(a.stop)
        stack.enter_context(devices(cfg))  # once A listens: their boot-ups are the first frames it hears
        wait_role(a, "active", 15)
        wait_until_sync(lambda: nodes_alive(a), 20, "A's nodes alive")
        wait_until_sync(lambda: node_detail(a, "display").get("nmt_state") == "operational", 20, "A started the AP05")
        # the PLC's writes through A: set point 1 valid, then set point 2 valid too
        write(a, p["set_point1"], 1000)
        write(a, p["control_word"], 0x0004)
        write(a, p["control_word"], 0x0204)
        b = start_member(tmp_path, cfg, "B", B_ID, 1, A_ID)
        stack.callback(b.stop)
        wait_role(b, "standby", 15)
        joined = len(bus.frames)
        wait_until_sync(
            lambda: {f.cob_id for f in bus.frames[joined:] if f.sender == "A" and f.delivered} >= {RPDO1, RPDO2},
            10, "A's keep-alive round heard by B",
        )  # fmt: skip
        # standing by, B serves what A sent (it never heard the writes themselves)
        wait_until_sync(lambda: read(b, p["set_point1"]) == 1000, 10, "B serves set point 1")
        assert (read(b, p["control_word"]) or 0) & ~0x0100 == 0x0204  # bit 8 the gateway's

        killed = len(bus.frames)
        kill(a)
        wait_role(b, "active", 10)
        wait_until_sync(
            lambda: {f.cob_id for f in bus.frames[killed:] if f.sender == "B"} >= {RPDO1, RPDO2},
            10, "B's keep-alive round",
        )  # fmt: skip
        before = [(f.cob_id, f.data) for f in bus.sent_by("A") if f.cob_id in (RPDO1, RPDO2)]
        after = [(f.cob_id, f.data) for f in bus.frames[killed:] if f.sender == "B" and f.cob_id in (RPDO1, RPDO2)]
        assert rpdos_resume_as_sent(before, after, GUARDING_BIT) == []

        # a write of set point 1 through B: RPDO1 keeps the control word set through A
        mark = len(bus.frames)
        write(b, p["set_point1"], 1111)
        sent = bus.wait_for(lambda f: f.sender == "B" and f.cob_id == RPDO1, after=mark)
        control = int.from_bytes(sent.data[6:8], "little") & ~0x0100
        assert (struct.unpack_from("<i", sent.data)[0], control) == (1111, 0x0204)
        assert [f for f in bus.frames[killed:] if f.cob_id == COB_NMT] == []


@contextmanager
def devices(cfg: Path) -> Iterator[None]:
    """The simulated devices (``canopen-gateway simulate``), member "devices" of the relay."""
    sim = subprocess.Popen(
        [*gateway_argv(False), "simulate", "-c", str(cfg)],
        cwd=ROOT, env={**os.environ, "CANOPEN_GATEWAY__CAN__CHANNEL": "devices"},
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        assert sim.stdout is not None and "simulating" in sim.stdout.readline()
        yield
    finally:
        stop_process(sim)
