"""The commands that read the gateway's Zenoh keys as the cloud does: ``get`` (one query,
every reply) and ``sub`` (the samples of a key expression), with the connect settings of the
config (``canopen_gateway.tools.zenoh_client``).

Imports: canopen_gateway.tools.zenoh_client, cli.load.
"""

from __future__ import annotations

import argparse

from canopen_gateway.cli.load import load


def cmd_get(args: argparse.Namespace) -> int:
    from canopen_gateway.tools.zenoh_client import run_get

    cfg, _ = load(args.config)
    return run_get(cfg, args.key, args.timeout)


def cmd_sub(args: argparse.Namespace) -> int:
    from canopen_gateway.tools.zenoh_client import run_sub

    cfg, _ = load(args.config)
    return run_sub(cfg, args.key, args.count, args.duration)
