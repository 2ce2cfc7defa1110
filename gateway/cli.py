"""Command line: ``canopen-gateway run|check|registers|keys|simulate|sdo|nmt|lss|eds|profile``.

Configuration problems are printed one per line (file, key path, what is allowed) and exit 2,
without a traceback. Imports everything it drives; nothing imports this module.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
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
    from gateway.bus.can_backend import interface_problem

    cfg = _load(path)
    problem = interface_problem(cfg.can.interface)
    if problem is not None:
        raise ConfigError([f"{cfg.source}: can.interface: {problem}"])
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
    from gateway.zenoh_bridge.bridge import PrefixInUse

    gw = Gateway(cfg, simulate=not args.no_simulate)
    try:
        asyncio.run(_run_until_signal(gw.start, gw.stop, gw.summary))
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
            f"{len(pdo_sigs)} process signals ({', '.join(pdo_sigs)}), "
            f"{len(sdo_sigs)} configuration objects"
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
    raise SystemExit(f"error: no node {node!r} in {cfg.source}; nodes: {', '.join(n.name for n in cfg.nodes)}")


def cmd_sdo(args: argparse.Namespace) -> int:
    from gateway.errors import GatewayError

    cfg = _load_for_bus(args.config)
    name = _node_name(cfg, args.node)
    cfg.master.sdo_timeout_s = args.timeout

    async def op(gw: Any) -> Any:
        if args.op == "read":
            return await gw.commands.sdo_read(name, args.object, args.type)
        if args.value is None:
            raise SystemExit("error: sdo write needs a VALUE")
        await gw.commands.sdo_write(name, args.object, args.value, args.type)
        return "OK"

    try:
        result = asyncio.run(_with_master(cfg, op))
    except GatewayError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
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


def cmd_lss(args: argparse.Namespace) -> int:
    from gateway.tools.lss import run_lss

    cfg = _load(args.config)
    return run_lss(cfg, args)


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
