"""Command line: ``canopen-gateway run|demo|check|registers|keys|simulate|sdo|nmt|get|sub|scan|monitor|decode|lss|eds|profile|fault|schema|dcf``.

Configuration problems are printed one per line (file, key path, what is allowed) and exit 2,
without a traceback; so are a CAN bus that cannot be opened and a start that fails. Imports everything it drives; nothing imports this package.

This module holds the parser and ``main``; the commands are in its modules: ``serve`` (run,
demo, simulate), ``summary`` (check, registers, keys), ``commission`` (sdo, nmt), ``cloud``
(get, sub), ``eds`` (eds, profile), ``bus_tools`` (scan, monitor, decode, lss, fault),
``plant`` (schema, dcf: what the plant's own tools read); ``load`` loads a command's
configuration.

Imports: gateway (version), canopen_gateway.config (ConfigError), canopen_gateway.runtime.startup (StartupError),
canopen_gateway.tools.bus_open (BusOpenError), load, serve, summary, commission, cloud, eds, bus_tools, plant.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence

from canopen_gateway import __version__
from canopen_gateway.cli.bus_tools import cmd_decode, cmd_fault, cmd_lss, cmd_monitor, cmd_scan
from canopen_gateway.cli.cloud import cmd_get, cmd_sub
from canopen_gateway.cli.commission import cmd_nmt, cmd_sdo, format_sdo_int
from canopen_gateway.cli.eds import cmd_eds_lint, cmd_eds_show, cmd_profile_init
from canopen_gateway.cli.load import (
    CONFIG_ENV,
    DEFAULT_CONFIG,
    EXIT_CONFIG,
    EXIT_FAILED,
    default_config,
)
from canopen_gateway.cli.plant import cmd_dcf, cmd_schema
from canopen_gateway.cli.serve import cmd_demo, cmd_run, cmd_simulate, demo_requested, error_line
from canopen_gateway.cli.summary import _count, cmd_check, cmd_keys, cmd_registers
from canopen_gateway.config import ConfigError
from canopen_gateway.runtime.startup import StartupError
from canopen_gateway.tools.bus_open import BusOpenError

__all__ = ["EXIT_CONFIG", "EXIT_FAILED", "_count", "build_parser", "format_sdo_int", "main"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="canopen-gateway",
        description="CANopen to Modbus TCP and Zenoh edge gateway.",
    )
    p.add_argument("--version", action="version", version=f"canopen-gateway {__version__}")
    add = p.add_subparsers(dest="command", required=True, metavar="COMMAND").add_parser
    _add_gateway_commands(add)
    _add_commissioning_commands(add)
    _add_file_commands(add)
    _add_bus_commands(add)
    _add_plant_commands(add)
    return p


#: a subcommand's parser added to the command line (``add_subparsers().add_parser``)
AddParser = Callable[..., argparse.ArgumentParser]


CONFIG_HELP = f"configuration YAML (default: ${CONFIG_ENV}, else {DEFAULT_CONFIG})"


def _with_config(sp: argparse.ArgumentParser, *, network: str | None = None) -> argparse.ArgumentParser:
    """``-c FILE``; ``network``: the command opens one network's bus, ``--network NAME``
    (needed when the config has several; ``network`` says what it does with it)."""
    sp.add_argument("-c", "--config", metavar="FILE", help=CONFIG_HELP)
    if network is not None:
        sp.add_argument("--network", metavar="NAME", help=network)
    return sp


#: ``--network``'s help of the commands that open one network's bus
ONE_NETWORK = "the CAN network (networks[].name) to work on; needed when the config has several"


def _with_log_format(sp: argparse.ArgumentParser) -> None:
    sp.add_argument("--log-format", choices=["text", "json"],
                    help="log lines as text or one JSON object per line (default: "
                    "CANOPEN_GATEWAY_LOG_FORMAT, else text)")  # fmt: skip


def _add_gateway_commands(add: AddParser) -> None:
    """run, demo, check, registers, keys, simulate, fault."""
    sp = _with_config(add("run", help="run the gateway"))
    sp.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    _with_log_format(sp)
    sp.add_argument("--no-simulate", action="store_true", help="ignore the simulate: section")
    sp.set_defaults(fn=cmd_run)

    sp = add("demo", help="run the gateway on the demo configuration (simulated devices)")
    sp.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    _with_log_format(sp)
    sp.set_defaults(fn=cmd_demo)

    sp = add(
        "check", help="validate a configuration (or the two of a pair) and summarise it"
    )
    sp.add_argument("-c", "--config", action="append", metavar="FILE",
                    help=f"{CONFIG_HELP}; twice: the two configs of a hot-standby pair, compared")  # fmt: skip
    sp.set_defaults(fn=cmd_check)

    sp = _with_config(add("registers", help="print the Modbus register map"))
    sp.add_argument("--format", choices=["markdown", "csv", "modicon", "kepware"],
                    help="markdown (default); csv; modicon: 6-digit Modicon addresses and IEC "
                    "types; kepware: a KEPServerEX tag import of one unit (--unit)")  # fmt: skip
    sp.add_argument("--csv", action="store_true", help="the same as --format csv")
    sp.add_argument("--unit", type=int, metavar="N", help="only the registers of this unit id")
    sp.set_defaults(fn=cmd_registers)

    sp = _with_config(add("keys", help="print the Zenoh key expressions"))
    sp.set_defaults(fn=cmd_keys)

    sp = _with_config(
        add("simulate", help="run only the simulated devices of a config"),
        network="only this network's devices (default: every network's, each on its own bus)",
    )
    sp.add_argument(
        "--nodes", help="comma-separated node names (default: simulate: section, else all)"
    )
    sp.add_argument("--log-level", choices=["debug", "info", "warning", "error"])
    _with_log_format(sp)
    sp.set_defaults(fn=cmd_simulate)

    sp = _with_config(
        add("fault", help="inject a fault into a running gateway's simulated node"), network=ONE_NETWORK
    )
    sp.add_argument("node", nargs="?", help="simulated node name (none: list nodes and actions)")
    sp.add_argument(
        "action", nargs="?", help="unplug, plug, heartbeat-off, heartbeat-on, emcy, emcy-clear"
    )
    sp.add_argument(
        "--url", help="the running gateway's web address (default: the port it says through its command socket, else health: of the config)"
    )
    sp.set_defaults(fn=cmd_fault)


def _add_commissioning_commands(add: AddParser) -> None:
    """sdo, nmt; get, sub (Zenoh)."""
    sp = _with_config(add("sdo", help="read or write an object by SDO (commissioning)"), network=ONE_NETWORK)
    sp.add_argument("op", choices=["read", "write"])
    sp.add_argument("node", help="node name or id")
    sp.add_argument("object", help="object, e.g. 0x6004:00")
    sp.add_argument("value", nargs="?", help="value to write")
    sp.add_argument(
        "--type", help="data type (uint8, int16, uint32, string, ...); default from the EDS"
    )
    sp.add_argument("--timeout", type=float, default=1.0, help="SDO timeout in seconds")
    sp.set_defaults(fn=cmd_sdo)

    sp = _with_config(add("nmt", help="send an NMT command"), network=ONE_NETWORK)
    sp.add_argument("command", choices=["start", "stop", "preop", "reset", "reset-comm"])
    sp.add_argument("node", help="node name, id, or 'all'")
    sp.set_defaults(fn=cmd_nmt)

    key_help = "key expression under the config's prefix (wire/value/position, */state); /KEY as written"
    sp = _with_config(add("get", help="ask the gateway's Zenoh keys as the cloud does (one line per reply)"))
    sp.add_argument("key", metavar="KEY", help=key_help + "; ?_time=... for history")
    sp.add_argument("--timeout", type=float, default=5.0, metavar="S", help="wait for replies")
    sp.set_defaults(fn=cmd_get)
    sp = _with_config(add("sub", help="print the samples of the gateway's Zenoh keys (one line each)"))
    sp.add_argument("key", metavar="KEY", help=key_help)
    sp.add_argument("--count", type=int, help="stop after this many samples")
    sp.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    sp.set_defaults(fn=cmd_sub)


def _add_file_commands(add: AddParser) -> None:
    """eds show|lint, profile init."""
    sp = add("eds", help="inspect an EDS or DCF (checked as when loaded)")
    eds_add = sp.add_subparsers(dest="eds_command", required=True, metavar="ACTION").add_parser
    show = eds_add("show", help="print the objects and the PDO mappings as tables")
    show.add_argument("file", metavar="FILE", help="EDS or DCF file")
    show.add_argument("--node-id", type=int, help="resolve $NODEID for this node id")
    show.add_argument(
        "--strict", action="store_true", help="list the warnings instead (as eds lint)"
    )
    show.set_defaults(fn=cmd_eds_show)
    lint = eds_add(
        "lint", help="list every deviation from CiA 306 (exit 1 warnings, 2 unusable)"
    )
    lint.add_argument("file", metavar="FILE", help="EDS or DCF file")
    lint.set_defaults(fn=cmd_eds_lint)

    sp = add("profile", help="device profiles (overlays on an EDS)")
    prof_add = sp.add_subparsers(dest="profile_command", required=True, metavar="ACTION").add_parser
    init = prof_add("init", help="write an editable overlay profile from an EDS")
    init.add_argument("--eds", required=True, metavar="FILE", help="EDS or DCF file")
    init.add_argument(
        "-o", "--output", metavar="FILE", help="profile .yaml to write (default: stdout)"
    )
    init.add_argument("--force", action="store_true", help="overwrite an existing file")
    init.set_defaults(fn=cmd_profile_init)


def _add_bus_commands(add: AddParser) -> None:
    """lss, scan, monitor, decode."""
    sp = _with_config(add("lss", help="LSS commissioning (CiA 305)"), network=ONE_NETWORK)
    sp.add_argument(
        "action",
        choices=[
            "inquire",
            "set-node-id",
            "set-bitrate",
            "store",
            "switch-global",
            "switch-selective",
            "auto-id",
            "fast-scan",
        ],
    )
    sp.add_argument("args", nargs="*", help="action arguments (see docs/canopen.md)")
    sp.set_defaults(fn=cmd_lss)

    sp = _with_config(
        add("scan", help="which node ids are on the bus, and what they are"), network=ONE_NETWORK
    )
    sp.add_argument(
        "--active", action="store_true", help="also read 1000h, 1008h, 1018h of ids 1..127"
    )
    sp.add_argument("--listen", type=float, default=1.5, metavar="S", help="passive listening time")
    sp.add_argument(
        "--timeout", type=float, default=0.1, metavar="S", help="SDO timeout of --active"
    )
    sp.set_defaults(fn=cmd_scan)

    sp = _with_config(add("monitor", help="print the bus traffic in CANopen words"), network=ONE_NETWORK)
    sp.add_argument(
        "--node", action="append", metavar="NAME|ID", help="only these nodes (repeat or comma)"
    )
    sp.add_argument("--kind", action="append", metavar="KIND",
                    help="only these kinds: nmt, sync, time, emcy, pdo, sdo, heartbeat, lss, other")  # fmt: skip
    sp.add_argument("--count", type=int, help="stop after this many lines")
    sp.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    sp.add_argument("--record", metavar="FILE",
                    help="also write every frame to FILE (.asc, .blf, .trc, .log, .csv: python-can's writers)")  # fmt: skip
    sp.set_defaults(fn=cmd_monitor)

    sp = _with_config(
        add("decode", help="print a recorded trace in CANopen words, one line per frame"),
        network="the CAN network the trace was recorded on; needed when the config has several",
    )
    sp.add_argument("file", metavar="FILE", help="a trace python-can reads (.asc, .blf, .trc, .log, .csv, ...)")
    sp.set_defaults(fn=cmd_decode)


def _add_plant_commands(add: AddParser) -> None:
    """schema, dcf."""
    sp = add("schema", help="print the JSON Schema of the configuration (or of a device profile)")
    sp.add_argument(
        "--profile", action="store_true", help="the schema of a device profile YAML instead"
    )
    sp.set_defaults(fn=cmd_schema)

    sp = _with_config(add("dcf", help="write a node's CiA 306 DCF as the gateway configures it"))
    sp.add_argument("--node", metavar="NAME", help="the node (config name)")
    sp.add_argument("--all", action="store_true", help="every node: <name>.dcf in -o DIR")
    sp.add_argument("-o", "--output", metavar="FILE|DIR", help="file (default: stdout); a directory with --all")
    sp.add_argument("--bitrate", type=int, metavar="KBIT",
                    help="the bus's bit rate in kbit/s (default: can.bitrate of the node's network)")  # fmt: skip
    sp.add_argument("--network", metavar="NAME", help="with --all: only this network's nodes")
    sp.set_defaults(fn=cmd_dcf)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and getattr(args, "command", None) == "lss" and not any(e.startswith("-") for e in extra):
        args.args += extra  # `lss switch-global -c FILE configuration`: the action's words after -c
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        if "config" in args and not args.config and not (args.command == "run" and demo_requested()):
            # -c left out: the environment, /etc (``run`` of the demo needs none)
            path = default_config()
            args.config = [path] if args.command == "check" else path
        return int(args.fn(args))
    except ConfigError as exc:
        for line in exc.problems:
            error_line(args, line)
        return EXIT_CONFIG
    except BusOpenError as exc:  # every command that opens the bus (canopen_gateway.tools.bus_open)
        error_line(args, exc.line)
        return EXIT_CONFIG
    except StartupError as exc:  # a part of a gateway or a commissioning master did not start
        for line in exc.lines(args.config):
            error_line(args, line)
        return EXIT_CONFIG
    except KeyboardInterrupt:
        return 130
