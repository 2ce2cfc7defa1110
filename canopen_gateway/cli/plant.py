"""The commands that hand the plant's own tools what they read: ``schema`` (the JSON Schema of
the configuration, or of a device profile, for an editor's YAML language server) and ``dcf``
(a node's CiA 306 DCF as the gateway configures it, ``canopen_gateway.device.dcf``).

Imports: canopen_gateway.canopen.cia305 (the bit rates), canopen_gateway.checks.json_schema, canopen_gateway.device.dcf, canopen_gateway.eds (read_text),
canopen_gateway.config (ConfigError), cli.load.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from canopen_gateway.canopen.cia305 import BIT_TIMING_KBPS
from canopen_gateway.cli.load import load, on_network
from canopen_gateway.config import ConfigError


def cmd_schema(args: argparse.Namespace) -> int:
    from canopen_gateway.checks.json_schema import config_schema, profile_schema

    schema = profile_schema() if args.profile else config_schema()
    sys.stdout.write(json.dumps(schema, indent=2) + "\n")
    return 0


def cmd_dcf(args: argparse.Namespace) -> int:
    """``dcf -c CONFIG --node NAME [-o FILE]`` or ``dcf -c CONFIG --all -o DIR [--network N]``."""
    loaded = load(args.config)
    full = loaded.cfg
    cfg, nodes = loaded if args.network is None else on_network(loaded, args.network, "dcf")
    names = [n.name for n in cfg.nodes]
    if args.all == (args.node is not None):
        raise ConfigError(["dcf: give --node NAME or --all (nodes: " + ", ".join(names) + ")"])
    if args.all and not args.output:
        raise ConfigError(["dcf --all: give -o DIR (a <node>.dcf per node is written there)"])
    if args.node is not None and args.node not in nodes:
        raise ConfigError([f"dcf: --node {args.node}: no such node; nodes: " + ", ".join(names)])
    rates = sorted(set(BIT_TIMING_KBPS.values()))  # CiA 301's table, as LSS sets them
    if args.bitrate is not None and args.bitrate not in rates:
        raise ConfigError([f"dcf --bitrate {args.bitrate}: not a CiA 301 bit rate; kbit/s, one of: "
                           + ", ".join(map(str, rates))])  # fmt: skip
    if args.all and args.bitrate is not None and len(cfg.network_names()) > 1:
        raise ConfigError([f"dcf --all --bitrate: {cfg.source} has {len(cfg.network_names())} networks, "
                           "each a bus of its own: give --network NAME with --bitrate (one of: "
                           f"{', '.join(cfg.network_names())})"])  # fmt: skip
    if args.node is not None:
        text = node_dcf(full, nodes[args.node], args.bitrate)
        if args.output:
            Path(args.output).write_text(text, encoding="utf-8")
            print(f"wrote {args.output}", file=sys.stderr)
        else:
            sys.stdout.write(text)
        return 0
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    texts = {name: node_dcf(full, nodes[name], args.bitrate) for name in names}  # every one, then write
    for name, text in texts.items():
        path = out / f"{name}.dcf"
        path.write_text(text, encoding="utf-8")
        print(f"wrote {path}", file=sys.stderr)
    return 0


def _bitrate_kbps(cfg: Any, given: int | None) -> int:
    """The bus's bit rate in kbit/s: ``--bitrate``, else ``can.bitrate`` (of the node's network:
    ``cfg`` is its view); a DCF never guesses it (SocketCAN's is set by ``ip link``, outside the
    config)."""
    if given is not None:
        return given
    if cfg.can.bitrate is None:
        key = cfg.qualify("can.bitrate")
        raise ConfigError(
            [f"{cfg.source}: {key}: not set (the interface's own, e.g. SocketCAN's `ip link`), "
             f"and a DCF says the bit rate: set {key} or give --bitrate KBIT (e.g. 500)"]
        )  # fmt: skip
    return round(cfg.can.bitrate / 1000)


def node_dcf(cfg: Any, rn: Any, bitrate: int | None) -> str:
    """One resolved node's DCF (``canopen_gateway.device.dcf.write_dcf``): ``[DeviceComissioning]`` of
    the node's own network (``cfg`` the whole config): its bit rate (``bitrate`` in kbit/s, else
    its ``can.bitrate``), its number, and its name (with one network, the gateway's)."""
    from canopen_gateway.device.dcf import Commissioning, write_dcf
    from canopen_gateway.eds import read_text

    node = rn.require()
    steps = node.boot_steps if node.cfg.configure else []
    network = cfg.network_of(node.name)
    view = cfg.network_view(network)
    number = cfg.network_names().index(network) + 1
    name = cfg.gateway.name if cfg.networks is None else network
    who = Commissioning(node.node_id, node.name, _bitrate_kbps(view, bitrate), name, number)
    path = node.lp.eds_path
    return write_dcf(read_text(path), path.name, steps, who, node.lp.od)
