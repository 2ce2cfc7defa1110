"""The commands that work on the bus beside or without a gateway: ``scan`` and ``monitor`` (a
bus of their own, with the simulated devices of the config when the bus is in-process and no
gateway runs; ``monitor --record FILE`` writes a trace), ``decode`` (a recorded trace in
CANopen words), ``lss`` (canopen_gateway.tools.lss) and ``fault`` (into a running gateway's simulated
node).

Imports: canopen_gateway.sim.buses (SimulatedBus), canopen_gateway.tools (beside, bus_open, lss, monitor), canopen_gateway.bus.scan, canopen_gateway.bus.trace,
canopen_gateway.northbound.frames, canopen_gateway.sim.faults_client, canopen_gateway.config, canopen_gateway.device.resolved (types),
cli.load.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from canopen_gateway.cli.load import EXIT_CONFIG, load, load_for_bus, on_network
from canopen_gateway.config import Config
from canopen_gateway.device.resolved import ResolvedNode


def cmd_fault(args: argparse.Namespace) -> int:
    from canopen_gateway.sim.faults_client import run_fault

    loaded = load(args.config)
    cfg, _ = on_network(loaded, args.network, "fault", args.node)
    if args.node is not None and args.action is None:
        print("error: fault NODE ACTION: give an action too (or neither, to list)", file=sys.stderr)
        return EXIT_CONFIG
    if args.url is None:  # the port the gateway of this config listens on, wherever it was set
        # asked of the whole config: the gateway has its socket when a bus of any network is
        # in-process, whichever network --network names
        cfg.health.port = _running_health_port(loaded.cfg) or cfg.health.port
    return run_fault(cfg, args.node, args.action, args.url)


def _running_health_port(cfg: Config) -> int | None:
    """The web port of the gateway running this config, as its command socket says (it may
    have been moved by a variable of its own shell); None when none answers there."""
    from canopen_gateway.tools import beside

    running = beside.find_local_gateway(cfg) if beside.in_process_bus(cfg) else None
    if running is None:
        return None
    running.close()
    port = running.hello.get("health_port")
    return port if isinstance(port, int) and port else None


def cmd_lss(args: argparse.Namespace) -> int:
    from canopen_gateway.tools.lss import run_lss

    cfg, nodes = on_network(load(args.config), args.network, "lss")
    _refuse_beside(cfg, "lss")
    return run_lss(cfg, nodes, args)


def _refuse_beside(cfg: Config, command: str) -> None:
    """On an in-process bus: exit 2 in one line when a gateway runs on it (a second process
    cannot join it), else say that the command acts on its own simulated devices."""
    from canopen_gateway.tools import beside

    if not beside.in_process_bus(cfg):
        return
    running = beside.find_local_gateway(cfg) or beside.find_running_gateway(cfg)
    line = beside.refusal(cfg, command)
    if running is not None:
        running.close()
        line = line or (
            f"error: {cfg.source}: {cfg.qualify('can.interface')}: virtual: the bus lives inside the gateway "
            f"running at {running.endpoint}, so `{command}` cannot join it; give both a bus "
            "they share (can.interface: remote, docs/canopen.md)"
        )
    if line is not None:
        print(line, file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    if cfg.simulated_nodes():
        print(beside.private_note(cfg), file=sys.stderr)


def _tool_bus(cfg: Config, nodes: dict[str, ResolvedNode], command: str) -> tuple[Any, Any]:
    """The bus a listening tool (scan, monitor) opens, and the simulated devices it runs when
    the bus is in-process and no gateway runs on it; exits 2 in one line when a gateway runs
    on an in-process bus (a second process cannot join it)."""
    from canopen_gateway.sim.buses import SimulatedBus
    from canopen_gateway.tools import beside
    from canopen_gateway.tools.bus_open import BusOpenError, open_bus, opening

    sim = None
    _refuse_beside(cfg, command)
    bus = open_bus(cfg)
    if beside.in_process_bus(cfg) and cfg.simulated_nodes():
        sim = SimulatedBus(cfg, nodes)
        try:
            with opening(cfg):
                sim.start()  # after the tool's bus is open: it sees the boot-ups
        except BusOpenError:
            bus.shutdown()
            raise
    return bus, sim


def cmd_scan(args: argparse.Namespace) -> int:
    from canopen_gateway.bus.scan import report, scan

    cfg, nodes = on_network(load_for_bus(args.config), args.network, "scan")
    bus, sim = _tool_bus(cfg, nodes, "scan")
    try:
        found = scan(
            bus,
            listen_s=args.listen,
            active=args.active,
            sdo_timeout_s=args.timeout,
            bitrate_bps=cfg.can.bitrate,
        )
    finally:
        bus.shutdown()
        if sim is not None:
            sim.stop()
    print("\n".join(report(found, cfg, args.active)))
    return 0


def cmd_monitor(args: argparse.Namespace) -> int:
    from canopen_gateway.bus.trace import trace_writer
    from canopen_gateway.northbound.frames import FrameDecoder, kind_filter, node_filter
    from canopen_gateway.tools.monitor import monitor

    cfg, resolved = on_network(load_for_bus(args.config), args.network, "monitor")
    try:
        nodes = node_filter(cfg, _split(args.node))
        kinds = kind_filter(_split(args.kind))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    decoder = FrameDecoder(cfg, resolved)
    record = None
    if args.record:
        try:
            record = trace_writer(args.record)
        except (ValueError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_CONFIG
    bus, sim = _tool_bus(cfg, resolved, "monitor")
    try:
        monitor(bus, decoder, sys.stdout, nodes=nodes, kinds=kinds, count=args.count,
                duration_s=args.duration, record=record)  # fmt: skip
    except KeyboardInterrupt:
        pass
    finally:
        bus.shutdown()
        if sim is not None:
            sim.stop()
        if record is not None:
            record.stop()
            print(f"recorded {args.record}", file=sys.stderr)
            if record.note() is not None:
                print(f"note: {record.note()}", file=sys.stderr)
    return 0


def cmd_decode(args: argparse.Namespace) -> int:
    """``decode -c CONFIG FILE``: a recorded trace in CANopen words, one line per frame."""
    from canopen_gateway.northbound.frames import FrameDecoder
    from canopen_gateway.tools.monitor import decode_file

    cfg, resolved = on_network(load(args.config), args.network, "decode")  # node ids: a network's
    try:
        decode_file(args.file, FrameDecoder(cfg, resolved), sys.stdout)
    except BrokenPipeError:
        raise  # the reader went away (`| head`): the program ends quietly (entry.main)
    except (OSError, ValueError, NotImplementedError) as exc:
        print(f"error: {args.file}: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    return 0


def _split(values: list[str] | None) -> list[str]:
    return [v for item in values or [] for v in item.split(",") if v]
