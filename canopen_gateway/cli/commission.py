"""The commissioning commands ``sdo`` (read / write an object) and ``nmt``: through a running
gateway when the bus lives inside it (``canopen_gateway.tools.beside``: its command socket, else its
Zenoh API), else with a passive master of their own on the bus (no server, no heartbeat, no
SYNC, no configuration of the nodes).

Imports: canopen_gateway.app, canopen_gateway.errors, canopen_gateway.tools.beside, canopen_gateway.tools.bus_open, canopen_gateway.device.resolved,
canopen_gateway.canopen.cia301, canopen_gateway.canopen.objref, canopen_gateway.config, cli.load.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from typing import Any

from canopen_gateway.cli.load import EXIT_CONFIG, EXIT_FAILED, load_for_bus, on_network
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode


async def _with_master(cfg: Config, nodes: dict[str, ResolvedNode], fn: Any) -> Any:
    """Open the bus with a master for one commissioning operation. Opens no server (no Modbus,
    Zenoh or health endpoint), so it runs beside a gateway that serves the same config."""
    from canopen_gateway.app import Gateway
    from canopen_gateway.tools.beside import in_process_bus
    from canopen_gateway.tools.bus_open import gateway_bus
    simulate = in_process_bus(cfg)  # on a shared bus the devices are there already, never doubled
    cfg.journal.path = None  # the gateway running this config holds its journal (and audits)
    cfg.modbus.enabled = False
    cfg.zenoh.enabled = False
    cfg.ascii = None
    cfg.command_socket.enabled = False  # the command is the one that would use it
    cfg.health.port = 0
    cfg.master.probe_at_start = False
    # no heartbeat and no SYNC of its own: beside a gateway they would be a second master's
    # (the gateway warns about a heartbeat on its COB-ID; a second SYNC doubles sync TPDOs)
    cfg.master.heartbeat_ms = 0
    cfg.master.sync_period_ms = 0
    for n in cfg.nodes:
        n.configure = False
    cfg.health.port = 0  # a commissioning command opens no server
    # passive: no NMT start or configuration of its own; SDO to nodes regardless of supervision
    # a bus that cannot open: one line, exit 2 (its driver would retry it otherwise)
    gw = Gateway(cfg, nodes, simulate=simulate, passive=True, bus_must_open=True)
    with gateway_bus(cfg):
        await gw.start()
    try:
        return await fn(gw)
    finally:
        await gw.stop()


def node_name(cfg: Config, node: str) -> str:
    for n in cfg.nodes:
        if n.name == node or str(n.node_id) == node:
            return n.name
    nodes = ", ".join(f"{n.name} (id {n.node_id})" for n in cfg.nodes)
    print(f"error: no node {node!r} in {cfg.source}; nodes: {nodes}", file=sys.stderr)
    raise SystemExit(EXIT_CONFIG)  # an argument error, like argparse's


def _beside(cfg: Config, command: str) -> Any:
    """A running gateway to go through (its Zenoh API), when the bus is in-process; exits 2
    with one line when a gateway runs that cannot be reached (see canopen_gateway.tools.beside)."""
    from canopen_gateway.tools import beside

    if not beside.in_process_bus(cfg):
        return None
    running = beside.find_local_gateway(cfg) or beside.find_running_gateway(cfg)
    if running is not None:
        return running
    line = beside.refusal(cfg, command) if cfg.simulated_nodes() else None
    if line is not None:
        print(line, file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    if cfg.simulated_nodes():
        print(beside.private_note(cfg), file=sys.stderr)
    return None


def _through(cfg: Config, running: Any, fn: Any) -> tuple[int, Any]:
    """Run ``fn(running)`` against a running gateway; errors as one line (exit 1), a write
    the gateway's Zenoh API refuses with what to do instead."""
    from canopen_gateway.tools.beside import RemoteError, ZenohGateway, no_socket_hint

    try:
        return 0, fn(running)
    except RemoteError as exc:
        hint = no_socket_hint(cfg) if exc.kind == "forbidden" and isinstance(running, ZenohGateway) else ""
        print(f"error: {exc} (through the running gateway at {running.endpoint}){hint}", file=sys.stderr)
        return EXIT_FAILED, None
    finally:
        running.close()


def cmd_sdo(args: argparse.Namespace) -> int:
    from canopen_gateway.errors import GatewayError

    cfg, nodes = on_network(load_for_bus(args.config), args.network, f"sdo {args.op}", args.node)
    name = node_name(cfg, args.node)
    cfg.master.sdo_timeout_s = args.timeout
    if args.op == "write" and args.value is None:
        print("error: sdo write needs a VALUE", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    running = _beside(cfg, f"sdo {args.op}")
    if running is not None:
        if args.op == "read":
            code, result = _through(cfg, running, lambda r: r.sdo_read(name, args.object, args.type))
        else:
            code, result = _through(
                cfg, running, lambda r: r.sdo_write(name, args.object, args.value, args.type) or "OK"
            )
        if code:
            return code
        # the value alone on stdout (scripts read it); where it came from on stderr
        print(f"sdo {args.op} of {name} through the running gateway at {running.endpoint}", file=sys.stderr)
        return _print_sdo(cfg, nodes, name, args, result)

    async def op(gw: Any) -> Any:
        if args.op == "read":
            return await gw.commands.sdo_read(name, args.object, args.type)
        await gw.commands.sdo_write(name, args.object, args.value, args.type)
        return "OK"

    try:
        result = asyncio.run(_with_master(cfg, nodes, op))
    except GatewayError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return _print_sdo(cfg, nodes, name, args, result)


def _print_sdo(
    cfg: Config, nodes: dict[str, ResolvedNode], name: str, args: argparse.Namespace, result: Any
) -> int:
    if isinstance(result, (bytes, bytearray)):
        result = bytes(result).hex(" ")
    if isinstance(result, int) and not isinstance(result, bool):
        result = format_sdo_int(result, args.type or _sdo_type(cfg, nodes, name, args.object))
    print(result)
    return 0


#: Width in bits of the integer types (profile type names, DS-301 basic types).
_INT_BITS = {"int8": 8, "int16": 16, "int24": 24, "int32": 32, "int64": 64}
_INT_BITS |= {f"u{k}": v for k, v in _INT_BITS.items()} | {"bool": 8}


def format_sdo_int(value: int, type_: str | None) -> str:
    """``-677 (0xFFFFFD5B)``: the value, then its bytes as the object's width in hex (two's
    complement for negative values); the width is the smallest that holds the value when the
    type is not known."""
    bits = _INT_BITS.get(type_ or "")
    if bits is None:
        bits = 8
        while not -(1 << (bits - 1)) <= value < (1 << bits) and bits < 64:
            bits *= 2
    return f"{value} (0x{value & ((1 << bits) - 1):0{bits // 4}X})"


def _sdo_type(cfg: Config, nodes: dict[str, ResolvedNode], name: str, obj: str) -> str | None:
    """The type of ``obj`` on node ``name``: the profile signal's, else the EDS's."""
    from canopen_gateway.canopen.cia301 import TYPE_NAMES
    from canopen_gateway.canopen.objref import ObjRef

    node = next(n for n in cfg.nodes if n.name == name)
    lp = nodes[node.name].lp
    ref = ObjRef.parse(obj)
    sig = lp.profile.signal_for(ref)
    if sig is not None:
        return sig.type
    var = lp.od_var(ref)
    return None if var is None else TYPE_NAMES.get(var.data_type)


def cmd_nmt(args: argparse.Namespace) -> int:
    cfg, nodes = on_network(load_for_bus(args.config), args.network, "nmt", args.node)
    name = "all" if args.node == "all" else node_name(cfg, args.node)
    running = _beside(cfg, "nmt")
    if running is not None:
        names = [n.name for n in cfg.nodes] if name == "all" else [name]
        code, _ = _through(cfg, running, lambda r: [r.nmt(n, args.command) for n in names])
        if code:
            return code
        print(f"NMT {args.command} sent to {name} through the running gateway at {running.endpoint}")
        return 0

    async def op(gw: Any) -> None:
        await gw.commands.nmt(name, args.command)

    asyncio.run(_with_master(cfg, nodes, op))
    print(f"NMT {args.command} sent to {name}")
    return 0
