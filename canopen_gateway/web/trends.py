"""Trends of the web console: the last minutes of every numeric process-data signal, sampled
from the process image into a bounded ring per node, for the node page's plots.

Rule 1: one writer. ``TrendStore.sample`` runs on the event loop only (the console's sampler
task, every ``TREND_PERIOD_S``); readers (``since``) run on the event loop too, so nothing here
needs a lock. The CAN reader thread is not involved: the image is read as the console's other
documents read it (``NodeImage.snapshot``).

Rule 2: never drawn as good when it is not. Each sample stores the value in engineering units
with its quality at that instant (``Quality``: 0 good, 1 stale, 2 bad). A bad sample (never
received since the node's start, or flagged invalid by the device) has no value; a stale one
keeps the last known value so the page can draw it apart (grey, dashed) from good data.

Rule 3: bounded. ``TREND_WINDOW_S / TREND_PERIOD_S`` samples per node (600), each a tuple of
one value and one quality per signal; a node's signals are fixed when the store is built.

What is a trend signal: numeric (integer or float type), carried by a TPDO of the node's PDO
layout, without named bits (a status word is shown in the table, not plotted).

Imports: image, web.views (signal metadata), northbound.scaling (engineering units), profiles.schema.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

from canopen_gateway.image import ProcessImage, Quality
from canopen_gateway.northbound.scaling import engineering
from canopen_gateway.profiles.schema import TYPE_BITS
from canopen_gateway.web.views import SignalMeta

TREND_PERIOD_S = 0.5
TREND_WINDOW_S = 300.0
TREND_SAMPLES = int(TREND_WINDOW_S / TREND_PERIOD_S)


def is_trend_signal(meta: SignalMeta) -> bool:
    s = meta.sig
    return (
        meta.source == "TPDO"
        and s.type in TYPE_BITS
        and s.type not in ("bool", "time_of_day")  # a time of day is text, not a curve
        and not s.bits
        and not s.values
    )


@dataclass(frozen=True)
class Sample:
    seq: int  # store-wide, increasing: a reader asks for what came after the last it saw
    ts: float  # wall clock (seconds since the epoch), for the time axis
    values: tuple[float | None, ...]  # engineering units, in the order of the node's signals
    quality: tuple[int, ...]  # Quality per signal


class TrendStore:
    """Per node, a ring of ``Sample`` for its trend signals (see the module docstring)."""

    def __init__(
        self,
        image: ProcessImage,
        meta: dict[str, dict[str, SignalMeta]],
        *,
        samples: int = TREND_SAMPLES,
    ):
        self.image = image
        self.signals: dict[str, tuple[SignalMeta, ...]] = {
            node: tuple(m for m in sigs.values() if is_trend_signal(m))
            for node, sigs in meta.items()
        }
        self.rings: dict[str, deque[Sample]] = {
            node: deque(maxlen=samples) for node, sigs in self.signals.items() if sigs
        }
        self.seq = 0

    def sample(self, now_monotonic: float, now_wall: float) -> None:
        """One sample of every trend signal of every node (event loop only)."""
        self.seq += 1
        for name, ring in self.rings.items():
            node = self.image.nodes.get(name)
            if node is None:
                continue
            snap = node.snapshot()
            values: list[float | None] = []
            quality: list[int] = []
            for meta in self.signals[name]:
                sv = snap[meta.sig.name] if meta.sig.name in snap else None
                if sv is None or sv.seq == 0:
                    values.append(None)
                    quality.append(int(Quality.BAD))
                    continue
                q = node.quality(sv, now_monotonic)
                v = engineering(meta.sig, sv.value, meta.scaling)
                ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                if q is Quality.BAD or not ok:
                    values.append(None)
                    quality.append(int(Quality.BAD))
                else:
                    values.append(float(v))
                    quality.append(int(q))
            ring.append(Sample(self.seq, now_wall, tuple(values), tuple(quality)))

    def since(self, node: str, after: int = 0) -> dict[str, Any]:
        """The node's samples newer than ``after``, as columns (the plot's data layout)."""
        ring = self.rings.get(node, ())
        new = [s for s in ring if s.seq > after]
        sigs = self.signals.get(node, ())
        return {
            "seq": self.seq,
            "period_s": TREND_PERIOD_S,
            "window_s": TREND_WINDOW_S,
            "signals": [{"name": m.sig.name, "unit": m.scaling.unit} for m in sigs],
            "t": [round(s.ts, 3) for s in new],
            "values": [[s.values[i] for s in new] for i in range(len(sigs))],
            "quality": [[s.quality[i] for s in new] for i in range(len(sigs))],
        }
