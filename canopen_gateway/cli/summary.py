"""The commands that say what a configuration compiles to: ``check`` (validated, each node
summarised, what may not do what is meant, what it will not check, the warnings of each EDS; given two configs, also
compared as a hot-standby pair), ``registers`` (the Modbus register map) and ``keys`` (the
Zenoh key expressions).

Imports: canopen_gateway.device.resolved, canopen_gateway.checks (config_warnings, config_notes, pair_of_networks), canopen_gateway.config
(ConfigError), canopen_gateway.eds,
canopen_gateway.northbound.regmap, canopen_gateway.northbound.plc_tags, canopen_gateway.northbound.keys, cli.load.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from canopen_gateway.cli.load import load, load_for_bus
from canopen_gateway.config import ConfigError


def cmd_check(args: argparse.Namespace) -> int:
    """One config as at every start; two (``-c A -c B``): each so, then compared as the two
    configs of a hot-standby pair (``canopen_gateway.checks.pair_problems``)."""
    from canopen_gateway.checks import pair_of_networks

    paths = [args.config] if isinstance(args.config, str) else list(args.config)
    if len(paths) == 1:
        cfg, nodes = load_for_bus(paths[0])
        _print_summary(paths[0], cfg, nodes)
        return 0
    if len(paths) != 2:
        raise ConfigError([f"check: -c given {len(paths)} times: one config, or the two of a pair"])
    problems: list[str] = []
    loaded = []
    for path in paths:
        try:
            cfg, nodes = load_for_bus(path)
        except ConfigError as exc:
            problems += exc.problems
            continue
        loaded.append((path, cfg, nodes))
    if len(loaded) == 2:
        (_, a, nodes_a), (_, b, nodes_b) = loaded
        problems += pair_of_networks(a, b, nodes_a, nodes_b)  # a pair per network
    if problems:
        raise ConfigError(problems)
    for path, cfg, nodes in loaded:
        _print_summary(path, cfg, nodes)
    print(f"{paths[0]}, {paths[1]}: a pair (the same bus, logical master and nodes)")
    return 0


def _print_summary(path: str, cfg: Any, nodes: Any) -> None:
    from canopen_gateway.checks import config_notes, config_warnings

    print(f"{path}: OK")
    if cfg.ascii is not None and cfg.ascii.enabled:
        gate = "reads, writes and NMT" if cfg.ascii.writes else "reads only"
        print(f"  CiA 309-3 ASCII gateway: {cfg.ascii.host}:{cfg.ascii.port}, {gate}")
    for number, view in enumerate(cfg.network_views(), start=1):
        if cfg.networks is not None:
            _print_network(view, number)
        _print_nodes(cfg, view, nodes)
        _print_pair(view, nodes)
    for _key, text in config_warnings(cfg, nodes):
        print(f"  warning: {text}")
    for _key, text in config_notes(cfg, nodes):
        print(f"  note: {text}")
    _print_eds_warnings(cfg, nodes)


def _print_nodes(cfg: Any, view: Any, nodes: Any) -> None:
    """One line per node of a network (``view``), and its profile's notes."""
    for n in view.nodes:
        lp = nodes[n.name].lp
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


def _print_pair(view: Any, nodes: Any) -> None:
    """``hot-standby pair: ...; worst take-over by this gateway 804 ms`` of a network in a pair
    (the figure the device-timeout warnings compare against)."""
    from canopen_gateway.checks.pair import takeover_worst_ms

    pair = view.master.redundancy
    if pair is None:
        return
    worst = takeover_worst_ms(view, {n.name: nodes[n.name] for n in view.nodes if n.name in nodes})
    figure = f"{worst} ms" if worst is not None else "none can be promised (see the warning)"
    print(f"  hot-standby pair: redundancy.node_id {pair.node_id}, priority {pair.priority}, peer "
          f"{pair.peer_node_id}; worst take-over by this gateway {figure}")  # fmt: skip


def _print_network(view: Any, number: int) -> None:
    """``network line1 (net 1): socketcan can0, 500000 bit/s, master node id 127``."""
    (net,) = view.network_sections()
    can = view.can.words()
    rate = f", {can['bitrate']} bit/s" if can["bitrate"] else ""
    print(f"  network {net.name} (net {number}): {can['interface']} {can['channel']}{rate}, "
          f"master node id {view.master.node_id}" + ("" if view.nodes else ", no nodes"))  # fmt: skip


def _print_eds_warnings(cfg: Any, nodes: Any) -> None:
    """One line per EDS/DCF of the config with its number of warnings. An RPDO entry the file
    marks ro is no warning when the node's profile says the device takes it from an RPDO only
    (``rpdo_only_writable``, from the manual: SDO writes refused); the line counts them apart."""
    from canopen_gateway.eds import EdsError, lint, load_eds

    seen: list[Any] = []
    for n in cfg.nodes:
        lp = nodes[n.name].lp
        path = lp.eds_path
        if path in seen:
            continue
        seen.append(path)
        try:
            warnings = lint(load_eds(path)).warnings
        except EdsError:
            continue
        rpdo_only = [f"entry {obj}: not writable (ro)" for obj in lp.profile.rpdo_only_writable]
        explained = [w for w in warnings if any(e in w.message for e in rpdo_only)]
        count = len(warnings) - len(explained)
        more = f" (canopen-gateway eds lint {path})" if count else ""
        why = (
            f"; {len(explained)} RPDO entries ro by SDO and written by RPDO only, as profile "
            f"{lp.family} says (rpdo_only_writable)"
            if explained
            else ""
        )
        print(f"  {path}: {count} warnings{why}{more}")


def _count(n: int, noun: str) -> str:
    """``1 process signal``, ``2 process signals``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def cmd_registers(args: argparse.Namespace) -> int:
    """The register map as Markdown, CSV, Modicon CSV or a KEPServerEX tag import
    (``canopen_gateway.northbound.plc_tags``); ``--unit`` keeps one unit id's registers."""
    from canopen_gateway.northbound import plc_tags
    from canopen_gateway.northbound.regmap import build_register_map

    cfg, nodes = load(args.config)
    rm = build_register_map(cfg, nodes)
    fmt = args.format or ("csv" if args.csv else "markdown")
    if args.csv and fmt != "csv":
        raise ConfigError([f"registers: --csv and --format {fmt}: give one"])
    units = sorted(rm.units)
    unit = args.unit
    if unit is not None and unit not in rm.units:
        raise ConfigError([f"registers: --unit {unit}: no such unit id; units: {_units(rm)}"])
    if fmt == "kepware" and unit is None:
        if len(units) != 1:
            raise ConfigError(
                [f"registers --format kepware: one device (unit id) per file: give --unit N; "
                 f"units: {_units(rm)}"]
            )  # fmt: skip
        unit = units[0]
    if fmt == "kepware":
        assert unit is not None
        text = plc_tags.to_kepware(rm, unit)
    elif fmt == "modicon":
        text = plc_tags.to_modicon(rm, unit)
    else:
        shown = rm if unit is None else rm.only_unit(unit)
        text = shown.to_csv() if fmt == "csv" else shown.to_markdown()
    sys.stdout.write(text)
    return 0


def _units(rm: Any) -> str:
    """``1 (wire), 2 (magnet), 247 (gateway)``."""
    return ", ".join(f"{u} ({rm.units[u] or 'gateway'})" for u in sorted(rm.units))


def cmd_keys(args: argparse.Namespace) -> int:
    from canopen_gateway.northbound.keys import render_keys

    cfg, nodes = load(args.config)
    sys.stdout.write(render_keys(cfg, nodes))
    return 0
