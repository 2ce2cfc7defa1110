"""The long-running commands: ``run`` (the gateway), ``demo`` (the gateway on the demo
configuration) and ``simulate`` (only the simulated devices of a config), each until SIGINT /
SIGTERM, with the logging they set up: text, or JSON lines with ``--log-format json`` /
``CANOPEN_GATEWAY_LOG_FORMAT=json`` (the start-up banner and the lines of a start that fails
too).

A gateway never pretends: ``run`` without its configuration file exits 2 with one line naming
the path and saying to mount or write one; the demo (simulated devices) runs only when asked
for, by ``demo`` or ``CANOPEN_GATEWAY_DEMO=1`` (the demo configuration: ``config/demo.yaml`` of
a checkout, or the file ``CANOPEN_GATEWAY_DEMO_CONFIG`` names; the image sets it).

Imports: canopen_gateway.app, canopen_gateway.sim.buses, canopen_gateway.config (ConfigError), canopen_gateway.runtime.startup,
canopen_gateway.runtime.fdlimit, canopen_gateway.runtime.logformat (text or JSON lines),
canopen_gateway.runtime.sd_notify (systemd),
canopen_gateway.tools.bus_open, cli.load.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys
import time
from collections.abc import Callable
from typing import Any

from canopen_gateway.cli.load import EXIT_CONFIG, EXIT_FAILED, load_for_bus, on_network
from canopen_gateway.config import ConfigError
from canopen_gateway.runtime.logformat import TEXT_FORMAT, JsonFormatter, json_line, log_format


def setup_logging(level: str, log_format: str = "text") -> None:
    """Log lines on stderr, as text or one JSON object per line (``canopen_gateway.runtime.logformat``)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if log_format == "json" else logging.Formatter(TEXT_FORMAT))
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO), handlers=[handler])
    for noisy in ("pymodbus", "can", "canopen", "zenoh"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    socketcand = logging.getLogger("can.interfaces.socketcand.socketcand")
    if _socketcand_partial_read not in socketcand.filters:
        socketcand.addFilter(_socketcand_partial_read)


#: python-can's socketcand client warns whenever a TCP read ends inside a frame's text, which
#: on a busy bus is about a hundred times a second; it reads on and loses nothing. Its other
#: warnings (bad data, frames it cannot parse, a message it discards) stay.
SOCKETCAND_PARTIAL_READ = "Got incomplete message => waiting for more data"


def _socketcand_partial_read(record: logging.LogRecord) -> bool:
    return record.msg != SOCKETCAND_PARTIAL_READ


async def run_until_signal(
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


def resolve_log_format(args: argparse.Namespace) -> str:
    """``--log-format``, else ``CANOPEN_GATEWAY_LOG_FORMAT``; kept in ``args.log_format`` so
    that the lines ``cli.main`` prints of a failed start are in the same format."""
    try:
        args.log_format = log_format(args.log_format)
    except ValueError as exc:
        args.log_format = "text"
        raise ConfigError([f"error: {exc}"]) from None
    return str(args.log_format)


def error_line(args: argparse.Namespace, line: str) -> None:
    """A line of a start that fails, on stderr: as it is, or as a JSON log object."""
    json_mode = getattr(args, "log_format", None) == "json"
    print(json_line(line, "error") if json_mode else line, file=sys.stderr)


#: file descriptors of a gateway beyond its client connections: listeners, the CAN bus, Zenoh's
#: sockets and threads' pipes, the journal, the console's connections and streams
BASE_FILES = 256


def files_needed(cfg: Any) -> int:
    """Open files a gateway of ``cfg`` may need with every connection cap reached."""
    return BASE_FILES + (cfg.modbus.max_connections if cfg.modbus.enabled else 0)


#: ``CANOPEN_GATEWAY_DEMO=1``: ``run`` runs the demo; ``..._DEMO_CONFIG``: the demo's file
DEMO_ENV = "CANOPEN_GATEWAY_DEMO"
DEMO_CONFIG_ENV = "CANOPEN_GATEWAY_DEMO_CONFIG"
DEMO_CONFIG = "config/demo.yaml"  # a checkout's


def demo_config() -> str:
    return os.environ.get(DEMO_CONFIG_ENV) or DEMO_CONFIG


def demo_requested() -> bool:
    """``CANOPEN_GATEWAY_DEMO=1``: ``run`` runs the demo, whatever its ``-c`` says."""
    return os.environ.get(DEMO_ENV, "").strip() in ("1", "true", "yes")


def cmd_demo(args: argparse.Namespace) -> int:
    """The gateway on the demo configuration: simulated devices, asked for by name."""
    args.config = demo_config()
    args.no_simulate = False
    return cmd_run(args)


def cmd_run(args: argparse.Namespace) -> int:
    from canopen_gateway.app import Gateway
    from canopen_gateway.tools.bus_open import gateway_bus

    fmt = resolve_log_format(args)
    if demo_requested():
        args.config = demo_config()
    if not os.path.isfile(args.config):
        from canopen_gateway.cli.load import DEFAULT_CONFIG

        # the image's path: mount one there; any other path: a file name to check
        how = (f"mount yours at this path (docker run -v \"$PWD/gateway.yaml:{args.config}:ro\" ..., "
               "docs/deploy.md) or write one" if args.config == DEFAULT_CONFIG
               else "check the path, or write one (README: Configuration)")  # fmt: skip
        error_line(
            args,
            f"error: {args.config}: no configuration file there: {how}; the demo runs only when "
            f"asked for (canopen-gateway demo, or {DEMO_ENV}=1)",
        )
        return EXIT_CONFIG
    cfg, nodes = load_for_bus(args.config)
    setup_logging(args.log_level or cfg.gateway.log_level, fmt)
    from canopen_gateway.runtime.fdlimit import raise_file_limit
    from canopen_gateway.runtime.startup import StartupError

    raise_file_limit(files_needed(cfg))

    # a bus that cannot open at start: one line, exit 2 (cli.main); opened once, by the gateway
    gw = Gateway(cfg, nodes, simulate=not args.no_simulate, bus_must_open=True, freeze_gc=True)
    banner = (lambda: json_line(gw.summary())) if fmt == "json" else gw.summary
    start, stop = with_systemd(gw)
    try:
        with gateway_bus(cfg):
            asyncio.run(run_until_signal(start, stop, banner))
    except StartupError as exc:  # a port in use, a file missing: one line, everything closed
        for line in exc.lines(args.config):  # every port in use, one line each
            error_line(args, line)
        return EXIT_CONFIG
    except OSError as exc:
        error_line(args, f"error: {exc}")
        return EXIT_FAILED
    return 0


def with_systemd(gw: Any) -> tuple[Callable[[], Any], Callable[[], Any]]:
    """The gateway's start and stop, telling systemd (``NOTIFY_SOCKET``): READY=1 once
    started (every listener open), STATUS= lines, WATCHDOG=1 while the event loop and every
    network's CAN reader go round, STOPPING=1 when the stop begins (``canopen_gateway.runtime.sd_notify``)."""
    from canopen_gateway.runtime.sd_notify import SystemdNotifier

    notifier = SystemdNotifier.from_env()
    tasks: list[asyncio.Task[None]] = []

    def status() -> str:
        doc = gw.status()
        up = sum(1 for n in doc["nodes"].values() if n["operational"])
        nets = doc["networks"]
        buses = (f"bus {doc['bus']['state']}" if len(nets) == 1 else
                 "buses " + ", ".join(f"{name} {n['bus']['state']}" for name, n in nets.items()))  # fmt: skip
        return f"{'ready' if doc['ready'] else 'not ready'}: {up}/{len(doc['nodes'])} nodes operational, {buses}"

    async def start() -> None:
        notifier.send("STATUS=starting")
        await gw.start()
        notifier.ready(f"{status()}; {gw.summary()}")
        tasks.append(asyncio.get_running_loop().create_task(notifier.supervise(readers_go_round(gw), status)))

    async def stop() -> None:
        notifier.stopping()
        for t in tasks:
            t.cancel()
        await gw.stop()
        notifier.close()

    return start, stop


def readers_go_round(gw: Any) -> Callable[[], bool]:
    """systemd's watchdog's question of a gateway: every network's CAN reader went round since
    the last ask, and none died (one stuck reader is a gateway systemd restarts, whichever
    network it reads)."""
    turns: dict[str, int] = {}  # network name -> its reader's rounds when last asked

    def alive() -> bool:
        moved = []
        for net in gw.networks:
            now = net.driver.reader_turns
            moved.append(turns.get(net.name) != now)
            turns[net.name] = now
        dead = [name for name in gw.threads.failures() if name.startswith("can-reader")]
        return all(moved) and not dead

    return alive


def cmd_simulate(args: argparse.Namespace) -> int:
    from canopen_gateway.sim.buses import SimulatedBus
    from canopen_gateway.tools.bus_open import opening

    fmt = resolve_log_format(args)
    loaded = load_for_bus(args.config)
    cfg, nodes = loaded if args.network is None else on_network(loaded, args.network, "simulate")
    setup_logging(args.log_level or cfg.gateway.log_level, fmt)
    names = args.nodes.split(",") if args.nodes else [n.name for n in cfg.simulated_nodes()]
    if not names:
        names = [n.name for n in cfg.nodes]
    sim = SimulatedBus(cfg, nodes, names)

    async def start() -> None:
        for view, _ in sim.networks:  # each network's devices on its own bus
            with opening(view):  # a bus that cannot open: one line, exit 2 (cli.main)
                sim.start_network(view)

    async def stop() -> None:
        sim.stop()

    line = "; ".join(
        f"simulating {', '.join(f'{n}@{sim.nodes[n].node_id}' for n in names)} on {view.can.bus_kwargs()}"
        for view, names in sim.networks
    )
    line = json_line(line) if fmt == "json" else line
    asyncio.run(run_until_signal(start, stop, line))
    return 0
