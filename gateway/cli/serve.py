"""The long-running commands: ``run`` (the gateway) and ``simulate`` (only the simulated
devices of a config), each until SIGINT / SIGTERM, with the logging they set up.

Imports: gateway.app, gateway.config (blame), gateway.runtime.startup, gateway.zenoh_bridge.session (PrefixInUse),
gateway.tools.bus_open, cli.load.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import time
from collections.abc import Callable
from typing import Any

from gateway.cli.load import EXIT_CONFIG, EXIT_FAILED, load_for_bus, on_network
from gateway.config import blame


def setup_logging(level: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level.upper(), logging.INFO),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        stream=sys.stderr,
    )
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


def cmd_run(args: argparse.Namespace) -> int:
    from gateway.app import Gateway
    from gateway.tools.bus_open import gateway_bus

    cfg, nodes = load_for_bus(args.config)
    setup_logging(args.log_level or cfg.gateway.log_level)
    from gateway.runtime.startup import StartupError
    from gateway.zenoh_bridge.session import PrefixInUse

    # a bus that cannot open at start: one line, exit 2 (cli.main); opened once, by the gateway
    gw = Gateway(cfg, nodes, simulate=not args.no_simulate, bus_must_open=True, freeze_gc=True)
    try:
        with gateway_bus(cfg):
            asyncio.run(run_until_signal(gw.start, gw.stop, gw.summary))
    except StartupError as exc:  # a port in use, a file missing: one line, everything closed
        for line in exc.lines(args.config):  # every port in use, one line each
            print(line, file=sys.stderr)
        return EXIT_CONFIG
    except PrefixInUse as exc:  # a configuration problem: two gateways under one prefix
        where = blame("zenoh.prefix", args.config, cfg.env_keys)  # or the variable that set it
        print(f"error: {where}: zenoh.prefix: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    except OSError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from gateway.app import SimulatedBus
    from gateway.tools.bus_open import opening

    loaded = load_for_bus(args.config)
    cfg, nodes = loaded if args.network is None else on_network(loaded, args.network, "simulate")
    setup_logging(args.log_level or cfg.gateway.log_level)
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
    asyncio.run(run_until_signal(start, stop, line))
    return 0
