"""The commands on device descriptions: ``eds show`` (objects and PDO mappings as tables),
``eds lint`` (every deviation from CiA 306 with file:line) and ``profile init`` (an editable
overlay profile from an EDS).

Imports: canopen_gateway.eds, canopen_gateway.eds.show, canopen_gateway.config (ConfigError), cli.load.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from canopen_gateway.cli.load import EXIT_FAILED
from canopen_gateway.config import ConfigError


def _load(path: str) -> Any:
    """The device description at ``path``; a file that cannot be read raises ConfigError."""
    from canopen_gateway.eds import EdsError, load_eds

    try:
        return load_eds(path)
    except EdsError as exc:
        raise ConfigError(exc.problems) from None


def cmd_eds_show(args: argparse.Namespace) -> int:
    from canopen_gateway.eds.show import render

    eds = _load(args.file)
    if args.strict:
        return cmd_eds_lint(args)
    sys.stdout.write(render(eds, args.node_id))
    return _eds_summary(eds)


def _eds_summary(eds: Any) -> int:
    """Errors of ``eds`` on stderr (exit 2), else the number of warnings (exit 0)."""
    from canopen_gateway.eds import lint

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
    from canopen_gateway.eds import EdsError, lint, load_eds

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

    from canopen_gateway.eds.show import overlay_profile

    eds = _load(args.eds)
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
