"""Results of the benchmarks and their rendering as RESULTS.md.

A benchmark returns a ``Section``: a title, what was measured and how, a table of ``Row``s
(gateway figure, baseline figure, their ratio, the target and whether it is met) and free notes
(findings, causes of missed targets, proposals). ``render`` writes them all, after the machine
description, as Markdown.

Imports: bench.stats, the standard library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from bench.stats import Summary


@dataclass
class Row:
    figure: str  # what is measured, with its unit
    value: Summary  # the gateway's figure
    baseline_name: str = ""
    baseline: Summary | None = None
    ratio: Summary | None = None
    target: str = ""
    met: bool | None = None  # None: no target, or not measurable here
    digits: int = 0  # decimals of value and baseline


@dataclass
class Section:
    key: str
    title: str
    method: str
    rows: list[Row] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    error: str = ""


def fmt(x: float, digits: int) -> str:
    if math.isnan(x):
        return "n/a"
    if digits == 0:
        return f"{x:,.0f}"
    return f"{x:,.{digits}f}"


def fmt_summary(s: Summary | None, digits: int) -> str:
    if s is None or not s.valid:
        return ""
    if s.n == 1 or s.minimum == s.maximum:
        return fmt(s.median, digits)
    return (
        f"**{fmt(s.median, digits)}** ({fmt(s.minimum, digits)}..{fmt(s.maximum, digits)}; "
        f"IQR {fmt(s.q1, digits)}..{fmt(s.q3, digits)})"
    )


def _met(row: Row) -> str:
    if row.met is None:
        return "-" if not row.target else "n/a"
    return "met" if row.met else "**missed**"


def render_section(sec: Section) -> list[str]:
    out = [f"## {sec.title}", "", sec.method, ""]
    if sec.error:
        out += [f"**Not measured**: {sec.error}", ""]
    if sec.rows:
        out += [
            "| figure | gateway: median (min..max; IQR) | baseline | baseline: median (min..max) | ratio | target | |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in sec.rows:
            out.append(
                "| "
                + " | ".join(
                    [
                        r.figure,
                        fmt_summary(r.value, r.digits),
                        r.baseline_name,
                        fmt_summary(r.baseline, r.digits),
                        fmt_summary(r.ratio, 2),
                        r.target,
                        _met(r),
                    ]
                )
                + " |"
            )
        out.append("")
    for n in sec.notes:
        out.append(f"- {n}")
    if sec.notes:
        out.append("")
    out += [f"_Section run time {sec.elapsed_s:.1f} s._", ""]
    return out


def render(machine: dict[str, str], sections: list[Section], preamble: list[str]) -> str:
    out = ["# Benchmark results", ""]
    out += preamble
    out += ["", "| machine | |", "|---|---|"]
    out += [f"| {k} | {v} |" for k, v in machine.items()]
    out.append("")
    summary = [
        f"| {sec.title.split(':')[0]} | {r.figure} | {fmt(r.value.median, r.digits)} | "
        + (f"{fmt(r.ratio.median, 2)} x" if r.ratio is not None and r.ratio.valid else "")
        + f" | {r.target} | {_met(r)} |"
        for sec in sections
        for r in sec.rows
        if r.target
    ]
    if summary:
        out += [
            "## Targets at a glance",
            "",
            "| benchmark | figure | gateway, median | ratio to baseline, median | target | |",
            "|---|---|---|---|---|---|",
        ]
        out += summary
        out.append("")
    for sec in sections:
        out += render_section(sec)
    return "\n".join(out).rstrip() + "\n"
