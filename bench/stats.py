"""The benchmarks' statistics, which say so when there was nothing to measure.

A percentile of no values is ``None``, never an error: a benchmark reports "0 seen" with its
stack's last log lines (what a failed measurement needs to be understood), and its smoke test
fails with that message.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def percentile(values: Sequence[float], fraction: float) -> float | None:
    """The nearest-rank percentile (``fraction`` in 0 to 1) of ``values``; ``None`` for none."""
    if not values:
        return None
    ordered = sorted(values)
    return ordered[max(0, math.ceil(fraction * len(ordered)) - 1)]


def ms(seconds: float | None) -> str:
    """A figure in seconds as milliseconds for a report; a dash where nothing was measured."""
    return "—" if seconds is None else f"{seconds * 1000:.0f} ms"
