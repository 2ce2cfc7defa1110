"""Malformed and hostile Modbus TCP traffic over raw sockets: every request is answered as the
Modbus Application Protocol V1.1b3 says (or, for a broken MBAP header, the connection closed),
pipelined requests are all answered by transaction id, and the server keeps serving others."""

from __future__ import annotations

import asyncio
import contextlib
import random
import struct
from collections.abc import AsyncIterator

from pymodbus.client import AsyncModbusTcpClient

from canopen_gateway.app import Gateway
from tests.helpers import gateway_of, make_config, wait_until

WIRE = {"name": "wire", "node_id": 1, "profile": "sgh10"}
HOLD = {"wire": {"kind": "hold", "min": -5000, "max": 5000, "hold": -1234}}
POSITION = [0xFFFF, 0xFB2E]  # input registers 100-101 of unit 1: int32 -1234


@contextlib.asynccontextmanager
async def running() -> AsyncIterator[Gateway]:
    cfg = make_config([WIRE], zenoh={"enabled": False}, simulate={"nodes": "all", "motion": HOLD})
    gw = gateway_of(cfg)
    await gw.start()
    try:
        node = gw.image.nodes["wire"]
        await wait_until(lambda: node.operational() and node.signals["position"].seq, 5, "wire")
        yield gw
    finally:
        await gw.stop()


def adu(pdu: bytes, tid: int = 1, unit: int = 1, pid: int = 0, length: int | None = None) -> bytes:
    """An MBAP header (Modbus TCP guide 3.1.3) + PDU."""
    n = len(pdu) + 1 if length is None else length
    return struct.pack(">HHHB", tid, pid, n, unit) + pdu


async def read_adu(reader: asyncio.StreamReader) -> tuple[int, int, bytes]:
    head = await asyncio.wait_for(reader.readexactly(7), 2)
    tid, pid, length, unit = struct.unpack(">HHHB", head)
    assert pid == 0
    return tid, unit, await asyncio.wait_for(reader.readexactly(length - 1), 2)


async def ask(gw: Gateway, pdu: bytes, unit: int = 1) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
    try:
        writer.write(adu(pdu, tid=0x1234, unit=unit))
        tid, got_unit, response = await read_adu(reader)
        assert (tid, got_unit) == (0x1234, unit)
        return response
    finally:
        writer.close()


def read_input(address: int, count: int) -> bytes:
    return struct.pack(">BHH", 4, address, count)


async def test_unsupported_function_codes_answer_illegal_function() -> None:
    async with running() as gw:
        for fc in (0x07, 0x08, 0x0B, 0x11, 0x41, 0x64, 0x81):
            assert await ask(gw, bytes([fc, 0, 0, 0, 1])) == bytes([fc | 0x80, 0x01]), hex(fc)


MALFORMED = [
    (read_input(100, 0), "quantity 0"),
    (read_input(100, 126), "more than 125 registers"),
    (struct.pack(">BHH", 3, 100, 0xFFFF), "huge count"),
    (struct.pack(">BHH", 2, 0, 2001), "more than 2000 bits"),
    (struct.pack(">BHH", 1, 100, 0), "no coils"),
    (struct.pack(">BHH", 5, 100, 0x1234), "coil value neither FF00h nor 0000h"),
    (struct.pack(">BHHB", 16, 0, 0, 0), "write of 0 registers"),
    (struct.pack(">BHHB", 16, 0, 2, 3) + bytes(3), "byte count not 2 x quantity"),
    (struct.pack(">BHHB", 16, 0, 2, 4) + bytes(6), "more data than the byte count"),
    (struct.pack(">BHHB", 15, 100, 9, 1) + bytes(1), "byte count not ceil(quantity / 8)"),
    (struct.pack(">BHHHHB", 23, 0, 126, 0, 1, 2) + bytes(2), "rw reads over 125"),
    (struct.pack(">BHHHHB", 23, 0, 1, 0, 0, 0), "rw writes of 0 registers"),
    (struct.pack(">BH", 4, 100), "read request cut short"),
    (read_input(100, 2) + b"\x00", "read request too long"),
    (struct.pack(">BHB", 6, 0, 1), "write single register cut short"),
    (b"\x10", "function code alone"),
]


async def test_malformed_requests_answer_illegal_data_value() -> None:
    async with running() as gw:
        for pdu, why in MALFORMED:
            assert await ask(gw, pdu) == bytes([pdu[0] | 0x80, 0x03]), why


async def test_an_address_range_past_65535_answers_illegal_data_address() -> None:
    async with running() as gw:
        assert await ask(gw, read_input(0xFFFF, 2)) == b"\x84\x02"


async def test_invalid_mbap_headers_close_only_that_connection() -> None:
    async with running() as gw:
        good_r, good_w = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        try:
            for bad in (
                adu(read_input(100, 2), pid=1),  # not the Modbus protocol
                adu(b"", length=1),  # unit id without a function code
                adu(read_input(100, 2), length=300),  # longer than any Modbus frame
            ):
                r, w = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
                w.write(bad + adu(read_input(100, 2), tid=2))
                assert await asyncio.wait_for(r.read(), 2) == b"", "closed without an answer"
                w.close()
                good_w.write(adu(read_input(100, 2), tid=7))
                tid, _, pdu = await read_adu(good_r)
                assert tid == 7 and pdu == b"\x04\x04" + struct.pack(">2H", *POSITION)
        finally:
            good_w.close()


async def test_pipelined_requests_split_anywhere_are_all_answered_by_transaction_id() -> None:
    async with running() as gw:
        reader, writer = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        try:
            stream = b"".join(
                adu(read_input(100, 2) if t % 2 else read_input(1, 1), tid=t) for t in range(1, 41)
            )
            for cut in (5, 17, 100, 233, len(stream)):  # segments ending mid-frame
                writer.write(stream[:cut])
                await writer.drain()
                stream = stream[cut:]
                await asyncio.sleep(0.01)
            answers = dict(
                [(tid, pdu) for tid, _, pdu in [await read_adu(reader) for _ in range(40)]]
            )
            assert sorted(answers) == list(range(1, 41))
            assert answers[1] == b"\x04\x04" + struct.pack(">2H", *POSITION)
            assert answers[2] == b"\x04\x02\x00\x05", "NMT state operational"
        finally:
            writer.close()


async def test_reads_answered_at_once_and_requests_that_need_a_task_mix_in_one_stream() -> None:
    """Reads of the image are answered without a task; an unmapped address, a bit read and an
    identification request take the task path; in one pipelined stream every one is answered,
    by transaction id, and counted once."""
    async with running() as gw:
        store = gw.modbus.store
        before = store.requests
        reader, writer = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        try:
            pdus = {
                1: read_input(100, 2),  # position: the image
                2: read_input(0xFFFF, 2),  # past the end: exception
                3: bytes([0x02]) + struct.pack(">HH", 0, 1),  # discrete input: task path
                4: read_input(1, 1),  # NMT state
                5: bytes([0x2B, 0x0E, 0x01, 0x00]),  # FC 43/14: identification (task path)
                6: read_input(100, 2),
            }
            writer.write(b"".join(adu(pdu, tid=t) for t, pdu in pdus.items()))
            answers = {tid: pdu for tid, _, pdu in [await read_adu(reader) for _ in pdus]}
            assert sorted(answers) == sorted(pdus)
            position = b"\x04\x04" + struct.pack(">2H", *POSITION)
            assert answers[1] == answers[6] == position
            assert answers[2] == b"\x84\x02"
            assert answers[3] == b"\x02\x01\x01"  # discrete input 0 (alive): one byte, set
            assert answers[4] == b"\x04\x02\x00\x05", "NMT state operational"
            assert answers[5][:3] == b"\x2b\x0e\x01"  # MEI 14, basic identification
            assert store.requests - before == len(pdus)
        finally:
            writer.close()


async def test_more_requests_in_flight_than_the_limit_are_throttled_not_dropped() -> None:
    async with running() as gw:
        reader, writer = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        try:
            writer.write(b"".join(adu(read_input(100, 2), tid=t) for t in range(300)))
            tids = sorted([(await read_adu(reader))[0] for _ in range(300)])
            assert tids == list(range(300))
        finally:
            writer.close()


async def test_a_client_stalled_in_the_middle_of_a_frame_does_not_block_others() -> None:
    async with running() as gw:
        r1, w1 = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
        frame = adu(read_input(100, 2), tid=11)
        w1.write(frame[:5])
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=2)
        await client.connect()
        try:
            rr = await client.read_input_registers(100, count=2, device_id=1)
            assert rr.registers == POSITION
            w1.write(frame[5:])
            assert (await read_adu(r1))[0] == 11
        finally:
            client.close()
            w1.close()


async def test_random_garbage_from_several_clients_leaves_the_server_serving() -> None:
    rng = random.Random(20240611)
    async with running() as gw:
        baseline = len(gw.modbus.connections)
        writers = []
        for _ in range(6):
            r, w = await asyncio.open_connection("127.0.0.1", gw.modbus.port)
            w.write(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 600))))
            writers.append((r, w))
        for _, w in writers:
            await w.drain()
        client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.port, timeout=2)
        await client.connect()
        try:
            for _ in range(20):
                rr = await client.read_input_registers(100, count=2, device_id=1)
                assert rr.registers == POSITION
        finally:
            client.close()
        for _, w in writers:
            w.close()
        await wait_until(lambda: len(gw.modbus.connections) <= baseline, 3, "connections closed")
