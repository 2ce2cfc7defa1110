"""``python -m bench [name ...]``: run the benchmarks (all by default) and write RESULTS.md.

Names: ingest, latency, modbus, scale, startup, hotpath, outage, linerate, costs, floors, pair,
plc-first, journal, networks. Running a subset prints its sections
and leaves RESULTS.md as it is.

Imports: bench.*.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import pathlib
import time
import traceback
from collections.abc import Awaitable, Callable

from bench import (
    costs,
    floors,
    hotpath,
    ingest,
    journal,
    latency,
    linerate,
    modbus_rps,
    networks,
    pair,
    plc_first,
    scale,
    startup,
    zenoh_outage,
)
from bench.findings import findings
from bench.machine import describe, load_average
from bench.report import Section, render

BENCHES: dict[str, Callable[[], Awaitable[Section]]] = {
    "ingest": ingest.run,
    "latency": latency.run,
    "modbus": modbus_rps.run,
    "scale": scale.run,
    "startup": startup.run,
    "hotpath": hotpath.run,
    "outage": zenoh_outage.run,
    "linerate": linerate.run,
    "costs": costs.run,
    "floors": floors.run,
    "pair": pair.run,
    "plc-first": plc_first.run,
    "journal": journal.run,
    "networks": networks.run,
}
HERE = pathlib.Path(__file__).resolve().parent


async def _run_one(name: str) -> Section:
    t0 = time.perf_counter()
    try:
        sec = await BENCHES[name]()
    except Exception:  # noqa: BLE001 - one failing benchmark must not lose the others
        sec = Section(key=name, title=name, method="", error=traceback.format_exc(limit=6))
    sec.elapsed_s = time.perf_counter() - t0
    return sec


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    ap.add_argument("names", nargs="*", choices=[[], *BENCHES], metavar="name")
    args = ap.parse_args()
    names = args.names or list(BENCHES)
    logging.basicConfig(level=logging.ERROR)
    machine = describe()
    load_before = load_average()
    t0 = time.perf_counter()
    sections = []
    for name in names:
        print(f"[bench] {name} ...", flush=True)
        sec = asyncio.run(_run_one(name))
        print(
            f"[bench] {name} done in {sec.elapsed_s:.1f} s" + (" (FAILED)" if sec.error else ""),
            flush=True,
        )
        sections.append(sec)
    if not args.names:
        sections.append(findings(sections))
    machine["load average before / after"] = f"{load_before} / {load_average()}"
    machine["total run time"] = f"{time.perf_counter() - t0:.0f} s"
    preamble = [
        "Written by `python -m bench` (`make bench`). Every figure is the median of several "
        "repetitions with its spread (min..max; interquartile range); every ratio is the median "
        "of per-repetition ratios gateway / baseline, the two measured back to back in the same "
        "run. Nothing here is asserted by a test. The machine is shared: the load average "
        "below says how busy it was.",
    ]
    text = render(machine, sections, preamble)
    if args.names:
        print(text)
        return
    out = HERE / "RESULTS.md"
    out.write_text(text, encoding="utf-8")
    print(f"[bench] wrote {out}")


if __name__ == "__main__":
    main()
