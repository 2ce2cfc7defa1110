"""Summaries of repeated measurements: median with spread, percentiles, paired ratios.

Every figure of the benchmark suite is reported as the median of several repetitions with its
spread (min..max and the interquartile range), and every comparison as the median of the
per-repetition ratios gateway / baseline (the two are measured interleaved, so drift of the
machine cancels out in each pair).

Imports: the standard library only.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0..100) with linear interpolation between closest ranks."""
    if not values:
        return math.nan
    xs = sorted(values)
    if len(xs) == 1:
        return xs[0]
    pos = (len(xs) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(xs) - 1)
    return xs[lo] + (xs[hi] - xs[lo]) * (pos - lo)


@dataclass(frozen=True)
class Summary:
    """Median and spread of one figure over repetitions."""

    median: float
    minimum: float
    maximum: float
    q1: float
    q3: float
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> Summary:
        vals = [v for v in values if not math.isnan(v)]
        if not vals:
            return cls(math.nan, math.nan, math.nan, math.nan, math.nan, 0)
        return cls(
            statistics.median(vals),
            min(vals),
            max(vals),
            percentile(vals, 25),
            percentile(vals, 75),
            len(vals),
        )

    @property
    def valid(self) -> bool:
        return self.n > 0


def paired_ratios(numerators: Sequence[float], denominators: Sequence[float]) -> list[float]:
    """Per-repetition ratios (pairs measured back to back); NaN where the baseline is 0."""
    return [a / b if b else math.nan for a, b in zip(numerators, denominators, strict=True)]
