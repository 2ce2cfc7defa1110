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

Imports: can, zenoh, the standard library.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import struct
import threading
import time
from typing import Any

TPDO = struct.Struct("<ih")  # SGH10 TPDO1/TPDO2: position int32, velocity int16
POSITION_SCALE = 0.1


class Pipeline:
    def __init__(self, can_port: int, channel: str, endpoint: str, prefix: str, nodes: int):
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
        self.values: dict[int, tuple[int, int]] = {}
        self.frames = 0
        self.running = True
        self.thread = threading.Thread(target=self._read, name="can-reader", daemon=True)

    def _read(self) -> None:
        recv, unpack, values = self.bus.recv, TPDO.unpack_from, self.values
        pubs, stamp = self.pubs, self.session.new_timestamp
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
            old = values.get(node)
            values[node] = (pos, vel)
            ppub, vpub = pubs.get(node, (None, None))
            if ppub is None:
                continue
            ts = time.time()
            if old is None or old[0] != pos:
                ppub.put(f'{{"value":{pos * POSITION_SCALE!r},"ts":{ts!r}}}', timestamp=stamp())
            if old is None or old[1] != vel:
                vpub.put(f'{{"value":{vel},"ts":{ts!r}}}', timestamp=stamp())


class _Modbus(asyncio.Protocol):
    """Reads (function 3 or 4) answered from ``values``: 100-101 position, 102 velocity."""

    def __init__(self, values: dict[int, tuple[int, int]]) -> None:
        self.values = values
        self.buf = bytearray()
        self.transport: Any = None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        buf = self.buf
        buf += data
        while len(buf) >= 12:
            tid, _pid, length, unit, fc, address, count = struct.unpack_from(">HHHBBHH", buf)
            del buf[: 6 + length]
            pos, vel = self.values.get(unit, (0, 0))
            regs = {100: (pos >> 16) & 0xFFFF, 101: pos & 0xFFFF, 102: vel & 0xFFFF}
            words = [regs.get(a, 0) for a in range(address, address + count)]
            body = bytes((fc, 2 * count)) + struct.pack(f">{count}H", *words)
            self.transport.write(struct.pack(">HHHB", tid, 0, len(body) + 1, unit) + body)


async def _serve(p: Pipeline, modbus_port: int) -> None:
    loop = asyncio.get_running_loop()
    server = await loop.create_server(lambda: _Modbus(p.values), "127.0.0.1", modbus_port)
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    p.thread.start()
    print("ready", flush=True)
    await stop.wait()
    p.running = False
    server.close()


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m bench.pipeline", description=__doc__)
    ap.add_argument("--can-port", type=int, required=True)
    ap.add_argument("--channel", default="can0")
    ap.add_argument("--modbus-port", type=int, required=True)
    ap.add_argument("--listen", required=True)
    ap.add_argument("--prefix", default="canopen/linerate")
    ap.add_argument("--nodes", type=int, default=60)
    a = ap.parse_args()
    p = Pipeline(a.can_port, a.channel, a.listen, a.prefix, a.nodes)
    try:
        asyncio.run(_serve(p, a.modbus_port))
    finally:
        p.bus.shutdown()
        p.session.close()
        os._exit(0)


if __name__ == "__main__":
    main()
