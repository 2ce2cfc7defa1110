"""The CiA 309-3 ASCII gateway over TCP, with a plain asyncio socket client scripted from the
standard's syntax, against the running gateway on a python-can virtual bus: our simulator
(SGH10) and an independent stack (python canopen's LocalNode built from an EDS, which answers
SDO; the test sends its boot-up, heartbeat and EMCY). A sniffer on the bus sees the frames."""

from __future__ import annotations

import asyncio
import logging
import random
import re
import socket
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
import yaml

from canopen_gateway.app import Gateway
from canopen_gateway.canopen.states import NmtState
from canopen_gateway.cli import main
from tests.helpers import free_port, gateway_of, make_config, unique_channel, wait_until

EDS = Path(__file__).resolve().parents[1] / "data" / "eds" / "io401.eds"
WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
ERROR_LINE = re.compile(r"^(\[\d+\] )?ERROR:\d+$")
#: a bound on waiting for one line, so a broken gateway fails the test instead of hanging it
LINE_BOUND_S = 15.0


class Client:
    """A 309-3 client: writes request lines (CR LF), reads answer lines; event lines (they
    carry no ``[seq]``) are kept apart in ``events``."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.events: list[str] = []

    @classmethod
    async def connect(cls, port: int) -> Client:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        return cls(reader, writer)

    async def send(self, data: str | bytes) -> None:
        self.writer.write(data.encode("ascii") + b"\r\n" if isinstance(data, str) else data)
        await self.writer.drain()

    async def line(self) -> str:
        raw = await asyncio.wait_for(self.reader.readline(), LINE_BOUND_S)
        assert raw.endswith(b"\r\n"), raw
        return raw[:-2].decode("ascii")

    async def answer(self) -> str:
        """The next line that is not an event line."""
        while True:
            line = await self.line()
            if re.match(r"^\d+ \d+ [A-Z_]+", line):
                self.events.append(line)
                continue
            return line

    async def ask(self, request: str) -> str:
        await self.send(request)
        return await self.answer()

    async def event(self, match: str) -> str:
        """Wait for an event line starting with ``match`` (answers in between are an error)."""
        while True:
            for e in self.events:
                if e.startswith(match):
                    self.events.remove(e)
                    return e
            line = await self.line()
            assert re.match(r"^\d+ \d+ [A-Z_]+", line), f"answer {line!r} while waiting for an event"
            self.events.append(line)

    async def close(self) -> None:
        self.writer.close()
        try:
            await self.writer.wait_closed()
        except ConnectionError:
            pass


class Sniffer(can.Listener):
    """Every frame on the bus, as (COB-ID, data)."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes]] = []

    def on_message_received(self, msg: can.Message) -> None:
        self.frames.append((msg.arbitration_id, bytes(msg.data)))


@asynccontextmanager
async def sim_gateway(**ascii_cfg: Any) -> AsyncIterator[tuple[Gateway, Sniffer, can.BusABC]]:
    cfg = make_config(
        [WIRE],
        modbus={"enabled": False},
        zenoh={"enabled": False},
        ascii={"port": free_port(), **ascii_cfg},
    )
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    sniffer = Sniffer()
    notifier = can.Notifier(bus, [sniffer])
    gw = gateway_of(cfg)
    await gw.start()
    try:
        await wait_until(lambda: gw.image.nodes["wire"].operational(), 8, "wire operational")
        yield gw, sniffer, bus
    finally:
        await gw.stop()
        notifier.stop()
        bus.shutdown()


# --------------------------------------------------------------------------- simulator
async def test_read_the_vendor_id_of_1018h_01_as_u32_x32_and_by_its_eds_type() -> None:
    async with sim_gateway() as (gw, _s, _b):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 1 r 0x1018 1 u32") == "[1] 405"  # SGH10 manual 4.6: 195h
        assert await c.ask("[2] 1 1 read 0x1018 0x01 x32") == "[2] 0x00000195"
        assert await c.ask("[3] 1 r 0x1018 1") == "[3] 405"
        assert await c.ask("[4] 1 r 0x1008 0 vs") == "[4] SGH10"  # segmented upload
        assert await c.ask("[5] 1 r 0x6FFF 0 u32") == "[5] ERROR:0x06020000"  # the device's abort
        assert await c.ask("[6] 1 r 0x1018 1 u8") == "[6] ERROR:0x06070010"  # 4 bytes, not 1
        assert await c.ask("1 r 0x1018 1 u32") == "ERROR:101"  # the sequence is mandatory
        await c.close()


async def test_a_write_with_writes_on_reaches_the_device_and_reads_back() -> None:
    async with sim_gateway(writes=True) as (gw, sniffer, _b):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 1 w 0x6200 0 u16 25") == "[1] OK"
        assert gw.sim.nodes["wire"].get(0x1800, 5) == 25  # 6200h is 1800h:05 (SGH10 4.6)
        assert await c.ask("[2] 1 r 0x6200 0 u16") == "[2] 25"
        # the download on the bus: expedited, 2 bytes, 6200h:00, value 25 (CiA 301 7.2.4.3.3)
        assert (0x601, bytes([0x2B, 0x00, 0x62, 0x00, 25, 0, 0, 0])) in sniffer.frames
        await c.close()


async def test_writes_and_nmt_are_refused_with_100_when_writes_are_off_and_nothing_goes_south() -> None:
    async with sim_gateway(writes=False) as (gw, sniffer, _b):
        audit: list[dict[str, Any]] = []
        gw.commands.audit = audit.append
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 1 w 0x6200 0 u16 25") == "[1] ERROR:100"
        assert await c.ask("[2] 1 stop") == "[2] ERROR:100"
        assert await c.ask("[3] 0 reset node") == "[3] ERROR:100"
        assert await c.ask("[4] 1 r 0x6200 0 u16") == "[4] 10"  # reads always pass; not 25
        downloads = [f for f in sniffer.frames if f[0] == 0x601 and f[1][0] >> 5 == 1]
        assert not [f for f in downloads if f[1][1:3] == b"\x00\x62"]  # none to 6200h
        assert (0x000, bytes([0x02, 0x01])) not in sniffer.frames
        assert (0x000, bytes([0x81, 0x00])) not in sniffer.frames
        assert gw.image.nodes["wire"].health.nmt_state == NmtState.OPERATIONAL
        assert audit[0]["who"].startswith("ascii 127.0.0.1:") and audit[0]["what"] == "[1] 1 w 0x6200 0 u16 25"
        assert audit[0]["outcome"] == "refused: ascii.writes is false"
        await c.close()


async def test_a_client_outside_allowed_networks_is_closed_at_once_and_logged_with_its_address(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async with sim_gateway(allowed_networks=["127.0.0.1/32"]) as (gw, _s, _b):
        with caplog.at_level(logging.WARNING, "gateway.ascii"):
            reader, writer = await asyncio.open_connection("127.0.0.1", gw.ascii.port, local_addr=("127.0.0.2", 0))
            writer.write(b"[1] 1 r 0x1018 1 u32\r\n")
            assert await asyncio.wait_for(reader.read(), 5) == b""  # closed, nothing answered
            writer.close()
        assert gw.ascii.refused_clients == 1 and gw.ascii.requests == 0
        assert any("127.0.0.2" in r.getMessage() and "ascii.allowed_networks" in r.getMessage()
                   for r in caplog.records)  # fmt: skip
        c = await Client.connect(gw.ascii.port)  # this machine's own address is served
        assert await c.ask("[1] 1 r 0x1018 1 u32") == "[1] 405"
        await c.close()


async def test_nmt_stop_start_and_preop_to_all_are_seen_on_the_bus() -> None:
    async with sim_gateway(writes=True) as (gw, sniffer, _b):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 1 stop") == "[1] OK"
        await wait_until(lambda: (0x000, bytes([0x02, 0x01])) in sniffer.frames, 5, "NMT stop")
        await wait_until(lambda: gw.sim.nodes["wire"].nmt_state == 0x04, 5, "the device stopped")
        assert await c.ask("[2] 1 start") == "[2] OK"
        await wait_until(lambda: (0x000, bytes([0x01, 0x01])) in sniffer.frames[-50:], 5, "NMT start")
        assert await c.ask("[3] 0 preoperational") == "[3] OK"  # node 0: every node
        await wait_until(lambda: (0x000, bytes([0x80, 0x00])) in sniffer.frames, 5, "NMT pre-op to all")
        await c.close()


async def test_unknown_node_syntax_error_long_line_and_garbage_are_answered_and_the_connection_kept() -> None:
    async with sim_gateway() as (gw, _s, _b):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 9 r 0x1018 1 u32") == "[1] ERROR:107"  # node 9 is not configured
        assert await c.ask("[2] 1 r 0x1018") == "[2] ERROR:101"
        assert await c.ask("[3] r 0x1018 1") == "[3] ERROR:105"
        assert await c.ask("[4] 1 frobnicate") == "[4] ERROR:100"
        assert await c.ask("[5] 1 w 0x2000 0 vs " + "A" * 3000) == "[5] ERROR:101"
        garbage = random.Random(309).randbytes(16384)
        await c.send(garbage + b"\r\n[6] 1 r 0x1018 1 u32\r\n")
        answers = []
        while not (line := await c.answer()).startswith("[6]"):
            answers.append(line)
        assert line == "[6] 405"
        assert answers and all(ERROR_LINE.match(a) for a in answers), answers[:5]
        assert len(gw.ascii.connections) == 1
        await c.close()


async def test_two_clients_at_once_each_with_its_own_session_and_a_client_leaving_mid_request() -> None:
    async with sim_gateway() as (gw, _s, _b):
        a = await Client.connect(gw.ascii.port)
        b = await Client.connect(gw.ascii.port)
        assert await a.ask("[1] set node 1") == "[1] OK"
        # pipelined on a, interleaved with b: each answered in its own order
        await a.send("[2] r 0x1008 0 vs\r\n[3] r 0x1018 1 x32\r\n[4] r 0x1018 2 u32")
        await b.send("[1] r 0x1018 1")
        assert await b.answer() == "[1] ERROR:105"  # b has no default node: a's is a's
        await b.send("[2] 1 r 0x1018 1 u32")
        assert [await a.answer() for _ in range(3)] == ["[2] SGH10", "[3] 0x00000195", "[4] 4294967295"]
        assert await b.answer() == "[2] 405"
        # a client that sends a request and goes away at once harms nobody
        gone = await Client.connect(gw.ascii.port)
        await gone.send("[1] 1 r 0x1008 0 vs")
        await gone.close()
        assert await a.ask("[5] r 0x1018 1") == "[5] 405"
        await wait_until(lambda: len(gw.ascii.connections) == 2, 5, "the gone client dropped")
        await a.close()
        await b.close()


async def test_a_client_that_sends_its_requests_and_half_closes_gets_every_answer() -> None:
    async with sim_gateway() as (gw, _s, _b):
        c = await Client.connect(gw.ascii.port)
        c.writer.write(b"[1] 1 r 0x1018 1 u32\r\n[2] 1 r 0x1008 0 vs\r\n[3] set node 2\r\n")
        c.writer.write_eof()  # as `nc -N` does at the end of its input
        data = await asyncio.wait_for(c.reader.read(), LINE_BOUND_S)  # up to the gateway's close
        assert data == b"[1] 405\r\n[2] SGH10\r\n[3] ERROR:107\r\n"
        await c.close()


async def test_help_info_version_and_set_commands_answer_on_the_running_gateway() -> None:
    async with sim_gateway() as (gw, _s, _b):
        c = await Client.connect(gw.ascii.port)
        await c.send("[1] help")
        lines = []
        while not (line := await c.line()).startswith("[1]"):
            lines.append(line)
        assert line == "[1] OK" and any("r[ead]" in x for x in lines)
        assert re.fullmatch(r"\[2\] 0 0 \d+\.\d+ 0 3 3\.0 \d+\.\d+", await c.ask("[2] info version"))
        assert await c.ask("[3] set network 1") == "[3] OK"
        assert await c.ask("[4] set network 2") == "[4] ERROR:106"
        assert await c.ask("# a comment line gets no answer\r\n[5] set sdo_timeout 1000") == "[5] OK"
        await c.close()


async def test_a_reset_node_brings_a_boot_up_event_line_to_every_client() -> None:
    async with sim_gateway(writes=True, events=True) as (gw, _s, bus):
        a = await Client.connect(gw.ascii.port)
        b = await Client.connect(gw.ascii.port)
        assert await b.ask("[1] info version") != ""  # b is connected and served
        assert await a.ask("[1] 1 reset node") == "[1] OK"
        assert await a.event("1 1 BOOT_UP") == "1 1 BOOT_UP"
        assert await b.event("1 1 BOOT_UP") == "1 1 BOOT_UP"
        # an EMCY of the device (CiA 301 7.2.7: code 8130h, register 11h, 5 bytes)
        bus.send(can.Message(arbitration_id=0x081, data=[0x30, 0x81, 0x11, 1, 2, 3, 4, 5], is_extended_id=False))
        assert await a.event("1 1 EMCY") == "1 1 EMCY 8130 11 1 2 3 4 5"
        await a.close()
        await b.close()


async def test_a_configured_node_that_was_never_heard_is_answered_102_without_an_sdo() -> None:
    cfg = make_config(
        [WIRE], simulate={"nodes": []}, modbus={"enabled": False}, zenoh={"enabled": False},
        master={"probe_at_start": False}, ascii={"port": free_port()},
    )  # fmt: skip
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    sniffer = Sniffer()
    notifier = can.Notifier(bus, [sniffer])
    gw = gateway_of(cfg)
    await gw.start()
    try:
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 1 r 0x1018 1 u32") == "[1] ERROR:102"
        assert not [f for f in sniffer.frames if f[0] == 0x601]
        await c.close()
    finally:
        await gw.stop()
        notifier.stop()
        bus.shutdown()


async def test_the_start_line_names_the_ascii_address() -> None:
    async with sim_gateway() as (gw, _s, _b):
        assert f"CiA 309-3 ASCII 127.0.0.1:{gw.ascii.port} |" in gw.summary()


def test_check_prints_the_ascii_line_and_commissioning_commands_leave_its_port_alone(
    tmp_path: Path, capsys: Any
) -> None:
    with socket.socket() as taken:  # the port a serving gateway would hold
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        raw = {
            "can": {"interface": "virtual", "channel": unique_channel()},
            "nodes": [WIRE],
            "modbus": {"port": free_port()},
            "zenoh": {"enabled": False},
            "simulate": {"nodes": "all"},
            "ascii": {"port": port, "writes": True},
        }
        path = tmp_path / "gw.yaml"
        path.write_text(yaml.safe_dump(raw))
        assert main(["check", "-c", str(path)]) == 0
        assert f"  CiA 309-3 ASCII gateway: 127.0.0.1:{port}, reads, writes and NMT" in capsys.readouterr().out
        assert main(["sdo", "read", "-c", str(path), "wire", "0x1018:01"]) == 0
        assert "405" in capsys.readouterr().out


# --------------------------------------------------------------------------- LocalNode
_STATE = {"INITIALISING": 0x00, "PRE-OPERATIONAL": 0x7F, "OPERATIONAL": 0x05, "STOPPED": 0x04}


class Heartbeat(threading.Thread):
    """The LocalNode's heartbeat, sent by the test (state from its NMT slave)."""

    def __init__(self, bus: can.BusABC, node: canopen.LocalNode) -> None:
        super().__init__(daemon=True)
        self.bus, self.node, self.stop = bus, node, threading.Event()

    def run(self) -> None:
        while not self.stop.wait(0.05):
            state = _STATE.get(self.node.nmt.state, 0x7F)
            self.bus.send(can.Message(arbitration_id=0x700 + self.node.id, data=[state], is_extended_id=False))


def boot(node: canopen.LocalNode) -> None:
    """CiA 301 7.3.2: boot-up 0x700+id [00], then PRE-OPERATIONAL."""
    node.nmt.send_command(0x81)
    node.nmt.send_command(0x80)


@asynccontextmanager
async def local_gateway(
    master: dict[str, Any] | None = None, **ascii_cfg: Any
) -> AsyncIterator[tuple[Gateway, canopen.Network, canopen.LocalNode, can.BusABC, Heartbeat]]:
    cfg = make_config(
        [{"name": "io", "node_id": 5, "eds": str(EDS), "heartbeat_ms": 300}],
        simulate={"nodes": []},
        master={"probe_at_start": False, **(master or {})},
        modbus={"enabled": False},
        zenoh={"enabled": False},
        ascii={"port": free_port(), **ascii_cfg},
    )
    with EDS.open(encoding="utf-8") as fp:
        od = canopen.import_od(fp, 5)
    net = canopen.Network()
    net.connect(interface="virtual", channel=cfg.can.channel)
    node = canopen.LocalNode(5, od)
    net.add_node(node)
    bus = can.Bus(interface="virtual", channel=cfg.can.channel)
    gw = gateway_of(cfg)
    await gw.start()
    hb = Heartbeat(bus, node)
    try:
        boot(node)
        hb.start()
        await wait_until(lambda: gw.image.nodes["io"].operational(), 8, "io operational")
        yield gw, net, node, bus, hb
    finally:
        hb.stop.set()
        if hb.is_alive():
            hb.join()
        await gw.stop()
        bus.shutdown()
        node.nmt.stop_heartbeat()
        net.disconnect()


async def test_local_node_read_of_1018h_01_and_a_write_it_stores() -> None:
    async with local_gateway(writes=True) as (gw, _net, node, _bus, _hb):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 5 r 0x1018 1 u32") == "[1] 2748"  # 0xABC from the EDS
        assert await c.ask("[2] 5 r 0x1018 1 x32") == "[2] 0x00000ABC"
        assert await c.ask("[3] 5 w 0x1400 3 u16 250") == "[3] OK"
        assert node.sdo[0x1400][3].raw == 250  # stored by the device stack, not by us
        assert await c.ask("[4] 5 r 0x1400 3") == "[4] 250"
        assert await c.ask("[5] 5 w 0x1018 1 u32 1") == "[5] ERROR:0x06010002"  # read-only
        await c.close()


async def test_local_node_obeys_nmt_stop_and_start_sent_through_the_ascii_gateway() -> None:
    async with local_gateway(writes=True) as (gw, _net, node, _bus, _hb):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 5 stop") == "[1] OK"
        await wait_until(lambda: node.nmt.state == "STOPPED", 5, "the LocalNode stopped")
        assert await c.ask("[2] 5 start") == "[2] OK"
        await wait_until(lambda: node.nmt.state == "OPERATIONAL", 5, "the LocalNode started")
        assert await c.ask("[3] 5 preop") == "[3] OK"
        await wait_until(lambda: node.nmt.state == "PRE-OPERATIONAL", 5, "the LocalNode pre-op")
        await c.close()


async def test_local_node_write_refused_with_writes_off() -> None:
    async with local_gateway(writes=False) as (gw, _net, node, _bus, _hb):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 5 w 0x1400 3 u16 250") == "[1] ERROR:100"
        assert await c.ask("[2] 5 r 0x1400 3 u16") == "[2] 0"
        assert node.sdo[0x1400][3].raw == 0
        await c.close()


async def test_a_device_that_does_not_answer_sdo_gives_abort_05040000_on_the_bus_or_session_time_out() -> None:
    async with local_gateway({"sdo_timeout_s": 1.0, "sdo_retries": 0}) as (gw, net, _n, _b, _hb):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] 5 r 0x1018 1 u32") == "[1] 2748"
        net.unsubscribe(0x605)  # the device's SDO server falls silent; its heartbeat goes on
        assert await c.ask("[2] 5 r 0x1018 1 u32") == "[2] ERROR:0x05040000"  # the bus's time-out
        assert await c.ask("[3] set sdo_timeout 50") == "[3] OK"
        assert await c.ask("[4] 5 r 0x1018 2 u32") == "[4] ERROR:0x05040000"
        # the session's 50 ms answered first: the transfer is still waiting on the bus
        assert gw.master._waiting
        await c.close()


async def test_local_node_events_boot_up_emcy_heartbeat_lost_and_started() -> None:
    async with local_gateway(events=True) as (gw, _net, node, bus, hb):
        c = await Client.connect(gw.ascii.port)
        assert await c.ask("[1] info version") != ""
        boot(node)  # the device reboots: boot-up frame
        assert await c.event("1 5 BOOT_UP") == "1 5 BOOT_UP"
        bus.send(can.Message(arbitration_id=0x085, data=[0x10, 0x42, 0x05, 0, 0, 0, 0, 9], is_extended_id=False))
        assert await c.event("1 5 EMCY") == "1 5 EMCY 4210 05 0 0 0 0 9"
        # configured again after the reboot: its boot steps (1017h) are written, so canopen's
        # own heartbeat producer stays off once stopped
        await wait_until(
            lambda: gw.master.nodes["io"].lifecycle.state == "operational"
            and gw.image.nodes["io"].operational(),
            8,
            "io configured again",
        )
        hb.stop.set()
        hb.join()
        node.nmt.stop_heartbeat()  # canopen's own producer too (1017h was written at boot)
        assert await c.event("1 5 ERROR 203") == "1 5 ERROR 203 (Heartbeat lost)"
        again = Heartbeat(bus, node)
        again.start()
        try:
            assert await c.event("1 5 ERROR 202") == "1 5 ERROR 202 (Heartbeat started)"
        finally:
            again.stop.set()
            again.join()
        await c.close()
