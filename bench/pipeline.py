"""The bare pipeline of the line-rate rig: the least code that does what the gateway does for
the rig's clients, on the same libraries, so that a latency or CPU figure of the gateway can be
read against what the libraries and the machine give.

Run as its own process (``python -m bench.pipeline``): a python-can ``socketcand`` Bus read by
one thread, each TPDO of the 60 SGH10 unpacked with ``struct`` into a dict, each changed value
(position, velocity) put at once on its Zenoh key as a small JSON document with a timestamp, from
that same thread (no hand-off); on the main thread an asyncio protocol answers Modbus reads
(function 3 or 4) from that dict: registers 100-101 the position (int32, high word first), 102
the velocity, any other register 0. No node supervision, no quality, no register map, no
configuration: what is left is python-can's receive, Zenoh's put and asyncio's transport.
With ``--split`` the Modbus server is a process of its own reading the values from shared
memory (a record per node with a sequence counter: a reader never takes a torn record), the
design of two processes that the line-rate figures were asked to justify.

Imports: can and zenoh (in ``Pipeline`` only), the standard library.
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import signal
import struct
import threading
import time
from multiprocessing import shared_memory
from typing import Any

TPDO = struct.Struct("<ih")  # SGH10 TPDO1/TPDO2: position int32, velocity int16
POSITION_SCALE = 0.1
#: ``--split``: one record per node id in shared memory: sequence counter (odd while written),
#: position, velocity; a reader retries a record whose counter was odd or changed under it
RECORD = struct.Struct("<Iih")


class SharedValues:
    """node id -> (position, velocity) in shared memory (one writer, any readers)."""

    def __init__(self, name: str | None = None, nodes: int = 128) -> None:
        size = RECORD.size * nodes
        self.shm = shared_memory.SharedMemory(name=name, create=name is None, size=size)
        buf = self.shm.buf
        assert buf is not None
        self.buf = buf
        self.seq = [0] * nodes

    def __setitem__(self, node: int, value: tuple[int, int]) -> None:
        seq = self.seq[node] + 1
        off = node * RECORD.size
        RECORD.pack_into(self.buf, off, seq, 0, 0)  # odd: being written
        RECORD.pack_into(self.buf, off, seq + 1, value[0], value[1])
        self.seq[node] = seq + 1

    def get(self, node: int, default: tuple[int, int]) -> tuple[int, int]:
        if not 0 <= node < len(self.seq):
            return default
        off = node * RECORD.size
        while True:
            seq, pos, vel = RECORD.unpack_from(self.buf, off)
            if seq & 1:
                continue
            if RECORD.unpack_from(self.buf, off)[0] == seq:
                return (pos, vel) if seq else default


def _modbus_process(shm_name: str, port: int) -> None:
    """``--split``: the Modbus server in a process of its own, reading the shared values."""
    values = SharedValues(shm_name)

    async def serve() -> None:
        loop = asyncio.get_running_loop()
        server = await loop.create_server(lambda: _Modbus(values), "127.0.0.1", port)
        async with server:
            await server.serve_forever()

    asyncio.run(serve())


class Pipeline:
    def __init__(
        self, can_port: int, channel: str, endpoint: str, prefix: str, nodes: int, split: bool
    ):
        import logging

        import can
        import zenoh

        logging.getLogger("can").setLevel(logging.ERROR)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", f'["{endpoint}"]')
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.pubs = {
            i: (
                self.session.declare_publisher(f"{prefix}/n{i}/value/position"),
                self.session.declare_publisher(f"{prefix}/n{i}/value/velocity"),
            )
            for i in range(1, nodes + 1)
        }
        self.bus = can.Bus(interface="socketcand", host="127.0.0.1", port=can_port,
                           channel=channel, tcp_tune=True)  # fmt: skip
        #: node id -> (position, velocity) as the last TPDO carried them
        self.values: Any = SharedValues() if split else {}
        self.split = split
        self.frames = 0
        self.running = True
        self.thread = threading.Thread(target=self._read, name="can-reader", daemon=True)

    def _read(self) -> None:
        recv, unpack = self.bus.recv, TPDO.unpack_from
        pubs, stamp = self.pubs, self.session.new_timestamp
        last: dict[int, tuple[int, int]] = {} if self.split else self.values
        shared = self.values if self.split else None
        while self.running:
            msg = recv(0.1)
            if msg is None:
                continue
            self.frames += 1
            cob = msg.arbitration_id
            if not (0x181 <= cob & 0x7FF <= 0x2FF) or len(msg.data) != 6:
                continue
            node = cob & 0x7F
            pos, vel = unpack(msg.data)
            old = last.get(node)
            last[node] = (pos, vel)
            if shared is not None:
                shared[node] = (pos, vel)
            pair = pubs.get(node)
            if pair is None:
                continue
            ppub, vpub = pair
            ts = time.time()
            if old is None or old[0] != pos:
                ppub.put(f'{{"value":{pos * POSITION_SCALE!r},"ts":{ts!r}}}', timestamp=stamp())
            if old is None or old[1] != vel:
                vpub.put(f'{{"value":{vel},"ts":{ts!r}}}', timestamp=stamp())


class BareModbus(asyncio.Protocol):
    """Modbus/TCP reads (function 3 or 4) and nothing else: MBAP framing, ``registers`` for the
    answer's data, a count of the requests answered. Also the bare protocol of the floors
    section (``bench.floors``), which answers zeros."""

    def __init__(self, counter: list[int] | None = None) -> None:
        self.counter = counter if counter is not None else [0]
        self.buf = bytearray()
        self.transport: Any = None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def registers(self, unit: int, address: int, count: int) -> bytes:
        """The ``count`` registers at ``address`` of ``unit``, packed (zeros here)."""
        return bytes(2 * count)

    def data_received(self, data: bytes) -> None:
        buf = self.buf
        buf += data
        while len(buf) >= 12:
            tid, _pid, length, unit, fc, address, count = struct.unpack_from(">HHHBBHH", buf)
            del buf[: 6 + length]
            body = bytes((fc, 2 * count)) + self.registers(unit, address, count)
            self.transport.write(struct.pack(">HHHB", tid, 0, len(body) + 1, unit) + body)
            self.counter[0] += 1


class _Modbus(BareModbus):
    """Reads answered from ``values``: 100-101 position, 102 velocity, any other register 0."""

    def __init__(self, values: Any) -> None:
        super().__init__()
        self.values = values

    def registers(self, unit: int, address: int, count: int) -> bytes:
        pos, vel = self.values.get(unit, (0, 0))
        regs = {100: (pos >> 16) & 0xFFFF, 101: pos & 0xFFFF, 102: vel & 0xFFFF}
        return struct.pack(f">{count}H", *(regs.get(a, 0) for a in range(address, address + count)))


async def _serve(p: Pipeline, modbus_port: int) -> None:
    loop = asyncio.get_running_loop()
    child = server = None
    if p.split:
        child = multiprocessing.get_context("spawn").Process(
            target=_modbus_process, args=(p.values.shm.name, modbus_port), daemon=True
        )
        child.start()
    else:
        server = await loop.create_server(lambda: _Modbus(p.values), "127.0.0.1", modbus_port)
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    p.thread.start()
    print("ready", flush=True)
    await stop.wait()
    p.running = False
    if server is not None:
        server.close()
    if child is not None:
        child.terminate()
        p.values.shm.close()
        p.values.shm.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.pipeline", description=__doc__)
    ap.add_argument("--can-port", type=int, required=True)
    ap.add_argument("--channel", default="can0")
    ap.add_argument("--modbus-port", type=int, required=True)
    ap.add_argument("--listen", required=True)
    ap.add_argument("--prefix", default="canopen/linerate")
    ap.add_argument("--nodes", type=int, default=60)
    ap.add_argument("--split", action="store_true", help="the Modbus server in a second process")
    a = ap.parse_args()
    p = Pipeline(a.can_port, a.channel, a.listen, a.prefix, a.nodes, a.split)
    try:
        asyncio.run(_serve(p, a.modbus_port))
    finally:
        p.bus.shutdown()
        p.session.close()
        os._exit(0)


if __name__ == "__main__":
    main()
