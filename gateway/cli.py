"""Command line: ``canopen-gateway run|check|registers|keys|simulate|sdo|nmt|scan|monitor|lss|eds|profile|fault``.

Configuration problems are printed one per line (file, key path, what is allowed) and exit 2,
without a traceback. Imports everything it drives; nothing imports this module.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from gateway import __version__
from gateway.checks import load_checked_config
from gateway.config import Config, ConfigError

EXIT_CONFIG = 2
EXIT_FAILED = 1


def _load(path: str) -> Config:
    return load_checked_config(path)


def _load_for_bus(path: str) -> Config:
    """The config of a command that opens the CAN bus: also refuses an interface python-can
    cannot load (unknown name, plug-in not installed), in one line, before anything starts."""
    from gateway.bus.can_backend import can_section_problems, driver_problem, interface_problem
    from gateway.config import CAN_INTERFACE_MISSING, blame, env_keys

    cfg = _load(path)
    from_env = env_keys(os.environ)
    if "interface" not in cfg.can.model_fields_set:  # written in the file or the environment
        raise ConfigError([f"{cfg.source}: can.interface: {CAN_INTERFACE_MISSING}"])
    problem = interface_problem(cfg.can.interface) or driver_problem(cfg.can.interface)
    if problem is not None:
        raise ConfigError([f"{blame('can.interface', cfg.source, from_env)}: can.interface: {problem}"])
    problems = can_section_problems(cfg.can.model_dump(exclude_none=True))
    if problems:
        raise ConfigError([f"{blame(k, cfg.source, from_env)}: {k}: {why}" for k, why in problems])
    return cfg


def _setup_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    for noisy in ("pymodbus", "can", "canopen", "zenoh"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


async def _run_until_signal(
    starter: Any, stopper: Any, ready_line: str | Callable[[], str] | None = None
) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
        except (NotImplementedError, RuntimeError):
            pass
    await starter()
    if ready_line:
        print(ready_line() if callable(ready_line) else ready_line, flush=True)
    try:
        await stop.wait()
    finally:
        t0 = time.monotonic()
        try:
            await asyncio.wait_for(stopper(), timeout=1.5)
        except TimeoutError:
            logging.getLogger("gateway").warning("shutdown took too long; exiting anyway")
        logging.getLogger("gateway").info("stopped in %.0f ms", (time.monotonic() - t0) * 1000)


def cmd_run(args: argparse.Namespace) -> int:
    from gateway.app import Gateway

    cfg = _load_for_bus(args.config)
    _setup_logging(args.log_level or cfg.gateway.log_level)
    from gateway.startup import StartupError
    from gateway.zenoh_bridge.bridge import PrefixInUse

    gw = Gateway(cfg, simulate=not args.no_simulate)
    try:
        asyncio.run(_run_until_signal(gw.start, gw.stop, gw.summary))
    except StartupError as exc:  # a port in use, a file missing: one line, everything closed
        print(exc.line(args.config), file=sys.stderr)
        return EXIT_CONFIG
    except PrefixInUse as exc:  # a configuration problem: two gateways under one prefix
        print(f"error: {args.config}: zenoh.prefix: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    except OSError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from gateway.bus.resolved import node_of, resolve_config

    cfg = _load_for_bus(args.config)
    nodes = resolve_config(cfg)
    print(f"{args.config}: OK")
    if cfg.ascii is not None and cfg.ascii.enabled:
        gate = "reads, writes and NMT" if cfg.ascii.writes else "reads only"
        print(f"  CiA 309-3 ASCII gateway: {cfg.ascii.host}:{cfg.ascii.port}, {gate}")
    for n in cfg.nodes:
        lp = node_of(cfg, nodes, n).lp
        pdo_sigs = [s.name for s in lp.profile.signals if s.transport == "pdo"]
        sdo_sigs = [s.name for s in lp.profile.signals if s.transport == "sdo"]
        sim = " (simulated)" if n in cfg.simulated_nodes() else ""
        print(
            f"  node {n.name}: id {n.node_id}, {lp.profile.title or n.device}{sim}; "
            f"{_count(len(pdo_sigs), 'process signal')} ({', '.join(pdo_sigs)}), "
            f"{_count(len(sdo_sigs), 'configuration object')}"
        )
        for note in lp.notes:
            print(f"  warning: node {n.name}: {note}")
    _print_eds_warnings(cfg, nodes)
    return 0


def _print_eds_warnings(cfg: Any, nodes: Any) -> None:
    """One line per EDS/DCF of the config with its number of warnings."""
    from gateway.bus.resolved import node_of
    from gateway.eds import EdsError, lint, load_eds

    seen: list[Any] = []
    for n in cfg.nodes:
        path = node_of(cfg, nodes, n).lp.eds_path
        if path in seen:
            continue
        seen.append(path)
        try:
            count = len(lint(load_eds(path)).warnings)
        except EdsError:
            continue
        more = f" (canopen-gateway eds lint {path})" if count else ""
        print(f"  {path}: {count} warnings{more}")


def _count(n: int, noun: str) -> str:
    """``1 process signal``, ``2 process signals``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def cmd_registers(args: argparse.Namespace) -> int:
    from gateway.northbound.regmap import build_register_map

    cfg = _load(args.config)
    rm = build_register_map(cfg)
    sys.stdout.write(rm.to_csv() if args.csv else rm.to_markdown())
    return 0


def cmd_keys(args: argparse.Namespace) -> int:
    from gateway.northbound.keys import render_keys

    cfg = _load(args.config)
    sys.stdout.write(render_keys(cfg))
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from gateway.app import SimulatedBus

    cfg = _load(args.config)
    _setup_logging(args.log_level or cfg.gateway.log_level)
    names = args.nodes.split(",") if args.nodes else [n.name for n in cfg.simulated_nodes()]
    if not names:
        names = [n.name for n in cfg.nodes]
    sim = SimulatedBus(cfg, names)

    async def start() -> None:
        sim.start()

    async def stop() -> None:
        sim.stop()

    line = f"simulating {', '.join(f'{n}@{sim.nodes[n].node_id}' for n in sim.nodes)} on {cfg.can.bus_kwargs()}"
    asyncio.run(_run_until_signal(start, stop, line))
    return 0


async def _with_master(cfg: Config, fn: Any) -> Any:
    """Open the bus with a master for one commissioning operation. Opens no server (no Modbus,
    Zenoh or health endpoint), so it runs beside a gateway that serves the same config."""
    from gateway.app import Gateway

    cfg.modbus.enabled = False
    cfg.zenoh.enabled = False
    cfg.ascii = None
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
    gw = Gateway(cfg, simulate=True, passive=True)
    await gw.start()
    try:
        return await fn(gw)
    finally:
        await gw.stop()


def _node_name(cfg: Config, node: str) -> str:
    for n in cfg.nodes:
        if n.name == node or str(n.node_id) == node:
            return n.name
    nodes = ", ".join(f"{n.name} (id {n.node_id})" for n in cfg.nodes)
    print(f"error: no node {node!r} in {cfg.source}; nodes: {nodes}", file=sys.stderr)
    raise SystemExit(EXIT_CONFIG)  # an argument error, like argparse's


def _beside(cfg: Config, command: str) -> Any:
    """A running gateway to go through (its Zenoh API), when the bus is in-process; exits 2
    with one line when a gateway runs that cannot be reached (see gateway.tools.beside)."""
    from gateway.tools import beside

    if not beside.in_process_bus(cfg):
        return None
    running = beside.find_running_gateway(cfg)
    if running is not None:
        return running
    line = beside.refusal(cfg, command) if cfg.simulated_nodes() else None
    if line is not None:
        print(line, file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    if cfg.simulated_nodes():
        print(beside.private_note(cfg), file=sys.stderr)
    return None


def _through(running: Any, fn: Any) -> tuple[int, Any]:
    """Run ``fn(running)`` against a running gateway; errors as one line (exit 1)."""
    from gateway.tools.beside import RemoteError

    try:
        return 0, fn(running)
    except RemoteError as exc:
        print(f"error: {exc} (through the running gateway at {running.endpoint})", file=sys.stderr)
        return EXIT_FAILED, None
    finally:
        running.close()


def cmd_sdo(args: argparse.Namespace) -> int:
    from gateway.errors import GatewayError

    cfg = _load_for_bus(args.config)
    name = _node_name(cfg, args.node)
    cfg.master.sdo_timeout_s = args.timeout
    if args.op == "write" and args.value is None:
        print("error: sdo write needs a VALUE", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    running = _beside(cfg, f"sdo {args.op}")
    if running is not None:
        if args.op == "read":
            code, result = _through(running, lambda r: r.sdo_read(name, args.object, args.type))
        else:
            code, result = _through(
                running, lambda r: r.sdo_write(name, args.object, args.value, args.type) or "OK"
            )
        if code:
            return code
        return _print_sdo(cfg, name, args, result)

    async def op(gw: Any) -> Any:
        if args.op == "read":
            return await gw.commands.sdo_read(name, args.object, args.type)
        await gw.commands.sdo_write(name, args.object, args.value, args.type)
        return "OK"

    try:
        result = asyncio.run(_with_master(cfg, op))
    except GatewayError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return _print_sdo(cfg, name, args, result)


def _print_sdo(cfg: Config, name: str, args: argparse.Namespace, result: Any) -> int:
    if isinstance(result, (bytes, bytearray)):
        result = bytes(result).hex(" ")
    if isinstance(result, int) and not isinstance(result, bool):
        result = format_sdo_int(result, args.type or _sdo_type(cfg, name, args.object))
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


def _sdo_type(cfg: Config, name: str, obj: str) -> str | None:
    """The type of ``obj`` on node ``name``: the profile signal's, else the EDS's."""
    from gateway.bus.resolved import node_of, resolve_config
    from gateway.cia301 import TYPE_NAMES
    from gateway.objref import ObjRef

    node = next(n for n in cfg.nodes if n.name == name)
    lp = node_of(cfg, resolve_config(cfg, [name]), node).lp
    ref = ObjRef.parse(obj)
    sig = lp.profile.signal_for(ref)
    if sig is not None:
        return sig.type
    var = lp.od_var(ref)
    return None if var is None else TYPE_NAMES.get(var.data_type)


def cmd_nmt(args: argparse.Namespace) -> int:
    cfg = _load_for_bus(args.config)
    name = "all" if args.node == "all" else _node_name(cfg, args.node)
    running = _beside(cfg, "nmt")
    if running is not None:
        names = [n.name for n in cfg.nodes] if name == "all" else [name]
        code, _ = _through(running, lambda r: [r.nmt(n, args.command) for n in names])
        if code:
            return code
        print(f"NMT {args.command} sent to {name} through the running gateway at {running.endpoint}")
        return 0

    async def op(gw: Any) -> None:
        gw.commands.nmt(name, args.command)

    asyncio.run(_with_master(cfg, op))
    print(f"NMT {args.command} sent to {name}")
    return 0


def cmd_eds_show(args: argparse.Namespace) -> int:
    from gateway.eds import EdsError, load_eds
    from gateway.eds.show import render

    try:
        eds = load_eds(args.file)
    except EdsError as exc:
        raise ConfigError(exc.problems) from None
    if args.strict:
        return cmd_eds_lint(args)
    sys.stdout.write(render(eds, args.node_id))
    return _eds_summary(eds)


def _eds_summary(eds: Any) -> int:
    """Errors of ``eds`` on stderr (exit 2), else the number of warnings (exit 0)."""
    from gateway.eds import lint

    result = lint(eds)
    for p in result.errors:
        print(f"{p.path}:{p.line}: [{p.section}]: error: {p.message}", file=sys.stderr)
    if result.errors:
        return 2
    if result.warnings:
        print(f"{eds.path}: {len(result.warnings)} warnings (canopen-gateway eds lint {eds.path})", file=sys.stderr)  # fmt: skip
    return 0


def cmd_eds_lint(args: argparse.Namespace) -> int:
    """Every deviation with file:line: [section]; exit 0 clean, 1 warnings, 2 unusable."""
    from gateway.eds import EdsError, lint, load_eds

    try:
        eds = load_eds(args.file)
    except EdsError as exc:
        for line in exc.problems:
            print(line)
        return 2
    result = lint(eds)
    shown = args.file  # the file as the user named it
    for kind, problems in (("error", result.errors), ("warning", result.warnings)):
        for p in problems:
            where = f"[{p.section}]" if p.section else "(no section)"
            print(f"{shown}:{p.line}: {where}: {kind}: {p.message}")
    print(f"{shown}: {len(result.errors)} errors, {len(result.warnings)} warnings")
    return result.exit_code


def cmd_profile_init(args: argparse.Namespace) -> int:
    from pathlib import Path

    from gateway.eds import EdsError, load_eds
    from gateway.eds.show import overlay_profile

    try:
        eds = load_eds(args.eds)
    except EdsError as exc:
        raise ConfigError(exc.problems) from None
    if args.output:
        out = Path(args.output)
        if out.exists() and not args.force:
            print(f"error: {out} exists (use --force to overwrite)", file=sys.stderr)
            return EXIT_FAILED
        try:
            ref = str(eds.path.relative_to(out.resolve().parent))
        except ValueError:
            ref = str(eds.path)
        out.write_text(overlay_profile(eds, ref), encoding="utf-8")
        print(f"wrote {out}")
    else:
        sys.stdout.write(overlay_profile(eds, args.eds))
    return 0


def cmd_fault(args: argparse.Namespace) -> int:
    from gateway.sim.faults_client import run_fault

    cfg = _load(args.config)
    if args.node is not None and args.action is None:
        print("error: fault NODE ACTION: give an action too (or neither, to list)", file=sys.stderr)
        return EXIT_CONFIG
    return run_fault(cfg, args.node, args.action, args.url)


def cmd_lss(args: argparse.Namespace) -> int:
    from gateway.tools.lss import run_lss

    cfg = _load(args.config)
    return run_lss(cfg, args)


def _tool_bus(cfg: Config, command: str) -> tuple[Any, Any]:
    """The bus a listening tool (scan, monitor) opens, and the simulated devices it runs when
    the bus is in-process and no gateway runs on it; exits 2 in one line when a gateway runs
    on an in-process bus (a second process cannot join it)."""
    import can

    from gateway.app import SimulatedBus
    from gateway.tools import beside

    sim = None
    if beside.in_process_bus(cfg):
        running = beside.find_running_gateway(cfg)
        line = beside.refusal(cfg, command)
        if running is not None:
            running.close()
            line = line or (
                f"error: {cfg.source}: can.interface: virtual: the bus lives inside the gateway "
                f"running at {running.endpoint}, so `{command}` cannot join it; give both a bus "
                "they share (can.interface: remote, docs/canopen.md)"
            )
        if line is not None:
            print(line, file=sys.stderr)
            raise SystemExit(EXIT_CONFIG)
    bus = can.Bus(**cfg.can.bus_kwargs())
    if beside.in_process_bus(cfg) and cfg.simulated_nodes():
        print(beside.private_note(cfg), file=sys.stderr)
        sim = SimulatedBus(cfg)
        sim.start()  # after the tool's bus is open: it sees the boot-ups
    return bus, sim


def cmd_scan(args: argparse.Namespace) -> int:
    from gateway.bus.scan import report, scan

    cfg = _load_for_bus(args.config)
    bus, sim = _tool_bus(cfg, "scan")
    try:
        found = scan(bus, listen_s=args.listen, active=args.active, sdo_timeout_s=args.timeout)
    finally:
        bus.shutdown()
        if sim is not None:
            sim.stop()
    print("\n".join(report(found, cfg, args.active)))
    return 0


def cmd_monitor(args: argparse.Namespace) -> int:
    from gateway.northbound.frames import FrameDecoder, kind_filter, node_filter
    from gateway.tools.monitor import monitor

    cfg = _load_for_bus(args.config)
    try:
        nodes = node_filter(cfg, _split(args.node))
        kinds = kind_filter(_split(args.kind))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    decoder = FrameDecoder(cfg)
    bus, sim = _tool_bus(cfg, "monitor")
    try:
        monitor(bus, decoder, sys.stdout, nodes=nodes, kinds=kinds, count=args.count,
                duration_s=args.duration)  # fmt: skip
    except KeyboardInterrupt:
        pass
    finally:
        bus.shutdown()
        if sim is not None:
            sim.stop()
    return 0


def _split(values: list[str] | None) -> list[str]:
    return [v for item in values or [] for v in item.split(",") if v]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="canopen-gateway",
        description="CANopen to Modbus TCP and Zenoh edge gateway.",
    )
    p.add_argument("--version", action="version", version=f"canopen-gateway {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def with_config(sp: argparse.ArgumentParser) -> argparse.ArgumentParser:
        sp.add_argument("-c", "--config", required=True, metavar="FILE", help="configuration YAML")
        return sp

    sp = with_config(sub.add_parser("run", help="run the gateway"))
    sp.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    sp.add_argument("--no-simulate", action="store_true", help="ignore the simulate: section")
    sp.set_defaults(fn=cmd_run)

    sp = with_config(sub.add_parser("check", help="validate a configuration and summarise it"))
    sp.set_defaults(fn=cmd_check)

    sp = with_config(sub.add_parser("registers", help="print the Modbus register map"))
    sp.add_argument("--csv", action="store_true", help="CSV instead of a Markdown table")
    sp.set_defaults(fn=cmd_registers)

    sp = with_config(sub.add_parser("keys", help="print the Zenoh key expressions"))
    sp.set_defaults(fn=cmd_keys)

    sp = with_config(sub.add_parser("simulate", help="run only the simulated devices of a config"))
    sp.add_argument("--nodes", help="comma-separated node names (default: simulate: section, else all)")
    sp.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    sp.set_defaults(fn=cmd_simulate)

    sp = with_config(
        sub.add_parser("fault", help="inject a fault into a running gateway's simulated node")
    )
    sp.add_argument("node", nargs="?", help="simulated node name (none: list nodes and actions)")
    sp.add_argument("action", nargs="?", help="unplug, plug, heartbeat-off, heartbeat-on, emcy, emcy-clear")
    sp.add_argument("--url", help="the running gateway's web address (default: from health: of the config)")
    sp.set_defaults(fn=cmd_fault)

    sp = with_config(sub.add_parser("sdo", help="read or write an object by SDO (commissioning)"))
    sp.add_argument("op", choices=["read", "write"])
    sp.add_argument("node", help="node name or id")
    sp.add_argument("object", help="object, e.g. 0x6004:00")
    sp.add_argument("value", nargs="?", help="value to write")
    sp.add_argument("--type", help="data type (uint8, int16, uint32, string, ...); default from the EDS")
    sp.add_argument("--timeout", type=float, default=1.0, help="SDO timeout in seconds")
    sp.set_defaults(fn=cmd_sdo)

    sp = with_config(sub.add_parser("nmt", help="send an NMT command"))
    sp.add_argument("command", choices=["start", "stop", "preop", "reset", "reset-comm"])
    sp.add_argument("node", help="node name, id, or 'all'")
    sp.set_defaults(fn=cmd_nmt)

    sp = sub.add_parser("eds", help="inspect an EDS or DCF (checked as when loaded)")
    eds_sub = sp.add_subparsers(dest="eds_command", required=True, metavar="ACTION")
    show = eds_sub.add_parser("show", help="print the objects and the PDO mappings as tables")
    show.add_argument("file", metavar="FILE", help="EDS or DCF file")
    show.add_argument("--node-id", type=int, help="resolve $NODEID for this node id")
    show.add_argument("--strict", action="store_true", help="list the warnings instead (as eds lint)")
    show.set_defaults(fn=cmd_eds_show)
    lint = eds_sub.add_parser("lint", help="list every deviation from CiA 306 (exit 1 warnings, 2 unusable)")
    lint.add_argument("file", metavar="FILE", help="EDS or DCF file")
    lint.set_defaults(fn=cmd_eds_lint)

    sp = sub.add_parser("profile", help="device profiles (overlays on an EDS)")
    prof_sub = sp.add_subparsers(dest="profile_command", required=True, metavar="ACTION")
    init = prof_sub.add_parser("init", help="write an editable overlay profile from an EDS")
    init.add_argument("--eds", required=True, metavar="FILE", help="EDS or DCF file")
    init.add_argument("-o", "--output", metavar="FILE", help="profile .yaml to write (default: stdout)")
    init.add_argument("--force", action="store_true", help="overwrite an existing file")
    init.set_defaults(fn=cmd_profile_init)

    sp = with_config(sub.add_parser("lss", help="LSS commissioning (CiA 305)"))
    sp.add_argument(
        "action",
        choices=["inquire", "set-node-id", "set-bitrate", "store", "switch-global", "switch-selective", "auto-id"],
    )
    sp.add_argument("args", nargs="*", help="action arguments (see docs/canopen.md)")
    sp.set_defaults(fn=cmd_lss)

    sp = with_config(sub.add_parser("scan", help="which node ids are on the bus, and what they are"))
    sp.add_argument("--active", action="store_true", help="also read 1000h, 1008h, 1018h of ids 1..127")
    sp.add_argument("--listen", type=float, default=1.5, metavar="S", help="passive listening time")
    sp.add_argument("--timeout", type=float, default=0.1, metavar="S", help="SDO timeout of --active")
    sp.set_defaults(fn=cmd_scan)

    sp = with_config(sub.add_parser("monitor", help="print the bus traffic in CANopen words"))
    sp.add_argument("--node", action="append", metavar="NAME|ID", help="only these nodes (repeat or comma)")
    sp.add_argument("--kind", action="append", metavar="KIND",
                    help="only these kinds: nmt, sync, time, emcy, pdo, sdo, heartbeat, lss, other")  # fmt: skip
    sp.add_argument("--count", type=int, help="stop after this many lines")
    sp.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    sp.set_defaults(fn=cmd_monitor)

    return p


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.fn(args))
    except ConfigError as exc:
        for line in exc.problems:
            print(line, file=sys.stderr)
        return EXIT_CONFIG
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
