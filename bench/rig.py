"""The bench rig: gateway configs built in code, a frame injector, free ports, bounded waits.

Every benchmark builds its gateway from a config dict (private virtual CAN channel, Modbus,
Zenoh and health on free loopback ports) and feeds it raw frames from an ``Injector``: a Bus of
its own on the channel that only sends. It sends either through python-can's ``send`` (which
deep-copies every message for every receiver, a cost of the virtual bus only) or straight into
the receivers' queues (``send_direct``: the same message objects, no copy), so that the
injector is not the bottleneck of what is measured.

Imports: python-can, canopen_gateway.config, canopen_gateway.app. Never a test module.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import time
import uuid
from collections.abc import Callable, Iterable
from typing import Any

import can

from canopen_gateway.app import Gateway
from canopen_gateway.config import Config, ConfigError, parse_config
from canopen_gateway.device.resolved import resolve_nodes

#: SGH10 TPDO1 and TPDO2 (SGH10 manual 4.3.1.1 Table 5): position int32, velocity int16
SGH10_TPDO = struct.Struct("<ih")
TPDO1_BASE = 0x180  # DS-301 predefined connection set
TPDO2_BASE = 0x280
NMT_EC_BASE = 0x700
NMT_BOOTUP = 0x00  # DS-301 7.2.8.3.2.4 boot-up message
NMT_OPERATIONAL = 0x05  # DS-301 7.2.8.3.2.1 heartbeat state byte


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def unique_channel(tag: str) -> str:
    return f"bench-{tag}-{uuid.uuid4().hex[:10]}"


def bench_node(name: str, node_id: int, **extra: Any) -> dict[str, Any]:
    """An SGH10 node that is not configured by SDO at boot (the injector answers no SDO) and is
    alive from its first heartbeat on (no supervision timeout unless asked for)."""
    node: dict[str, Any] = {
        "name": name,
        "node_id": node_id,
        "profile": "sgh10",
        "configure": False,
        "supervision": "none",
    }
    node.update(extra)
    return node


def bench_config(nodes: list[dict[str, Any]], tag: str, **sections: Any) -> Config:
    """A validated config: private virtual channel, free loopback ports, no simulated nodes."""
    raw: dict[str, Any] = {
        "gateway": {"name": "bench", "log_level": "warning"},
        "can": {"interface": "virtual", "channel": unique_channel(tag)},
        "master": {
            "heartbeat_ms": 1000,
            "sync_period_ms": 0,
            "boot_timeout_s": 60,
            "probe_at_start": False,
        },
        "nodes": nodes,
        "modbus": {"host": "127.0.0.1", "port": free_port()},
        "zenoh": {"listen": [f"tcp/127.0.0.1:{free_port()}"], "publish": "every"},
    }
    for key, value in sections.items():
        if isinstance(value, dict) and isinstance(raw.get(key), dict):
            raw[key] = {**raw[key], **value}
        else:
            raw[key] = value
    return parse_config(raw, environ={})


def gateway_of(cfg: Config, **kwargs: Any) -> Gateway:
    """A gateway built from a bench config and its nodes, resolved here (the command line
    resolves them when it loads the file)."""
    nodes, problems = resolve_nodes(cfg)
    if problems:
        raise ConfigError([f"{key}: {text}" for key, text in problems])
    return Gateway(cfg, nodes, **kwargs)


def zenoh_endpoint(cfg: Config) -> str:
    return cfg.zenoh.listen[0]


class Injector:
    """A Bus on a virtual channel that only sends (its own receive queue is detached)."""

    def __init__(self, channel: str):
        self.bus: Any = can.Bus(interface="virtual", channel=channel)
        self._own = self.bus.queue
        self.bus.channel.remove(self._own)

    def send(self, msg: can.Message) -> None:
        """python-can's path: a deep copy per receiver, timestamp set to now."""
        self.bus.send(msg)

    def send_direct(self, msg: can.Message) -> None:
        """Straight into every receiver's queue, no copy (the message must not change after)."""
        for q in self.bus.channel:
            q.put(msg)

    def receivers(self) -> int:
        return len(self.bus.channel)

    def close(self) -> None:
        self.bus.channel.append(self._own)
        try:
            self.bus.shutdown()
        except KeyError:
            pass  # the last receiver left first and python-can already dropped the channel


def frame(cob_id: int, data: bytes, timestamp: float | None = None) -> can.Message:
    return can.Message(
        arbitration_id=cob_id,
        data=data,
        is_extended_id=False,
        timestamp=time.time() if timestamp is None else timestamp,
    )


def heartbeat(node_id: int, state: int = NMT_OPERATIONAL) -> can.Message:
    return frame(NMT_EC_BASE + node_id, bytes([state]))


def tpdo_frames(
    node_id: int, positions: Iterable[int], base: int = TPDO1_BASE
) -> list[can.Message]:
    """Prebuilt SGH10 TPDOs with the given positions (distinct values) and velocity 7."""
    pack = SGH10_TPDO.pack
    now = time.time()
    return [frame(base + node_id, pack(p, 7), now) for p in positions]


async def wait_until(cond: Callable[[], Any], timeout_s: float, what: str) -> Any:
    """Poll ``cond`` every 5 ms until truthy; raise TimeoutError after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(0.005)


async def start_gateway(cfg: Config, injector: Injector, node_ids: Iterable[int]) -> Gateway:
    """Start a gateway without simulated nodes and make the nodes alive and operational: a
    boot-up (so the master does not probe them by SDO: nobody would answer) then a heartbeat."""
    gw = gateway_of(cfg, simulate=False)
    await gw.start()
    ids = list(node_ids)
    for nid in ids:
        injector.send(heartbeat(nid, NMT_BOOTUP))
        injector.send(heartbeat(nid))
    await wait_until(
        lambda: all(gw.image.by_id[n].operational() for n in ids), 5.0, "nodes operational"
    )
    return gw
