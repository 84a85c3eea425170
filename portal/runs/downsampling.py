"""Fewer points that keep a line chart's shape: Largest-Triangle-Three-Buckets.

:func:`downsample` is what the run page and the API's chart series use (compiled, from
``tsdownsample``); :func:`lttb` is the algorithm written out, the reference the tests hold
it to. Both take the x and y values of one line and give the indices of the points to keep.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from tsdownsample import LTTBDownsampler

# A chart line's values: a list, or a column of a run.
Values = Sequence[float] | np.ndarray


def _downsample_checked(xs: Values, ys: Values, max_points: int) -> bool:
    """Check the arguments; True if there are more points than ``max_points``."""
    if len(ys) != len(xs):
        raise ValueError("xs and ys must have the same length")
    if max_points < 3:
        raise ValueError(f"max_points must be at least 3, got {max_points}")
    return len(xs) > max_points


def downsample(xs: Values, ys: Values, max_points: int) -> list[int]:
    """The indices of at most ``max_points`` samples that keep a line chart's shape:
    Largest-Triangle-Three-Buckets (see :func:`lttb`), compiled (``tsdownsample``), about a
    hundred times faster than in Python; the tests hold it to :func:`lttb`."""
    if not _downsample_checked(xs, ys, max_points):
        return list(range(len(xs)))
    x = np.asarray(xs, dtype=np.float64)
    y = np.asarray(ys, dtype=np.float64)
    return [int(i) for i in LTTBDownsampler().downsample(x, y, n_out=max_points)]


def lttb(xs: Sequence[float], ys: Sequence[float], max_points: int) -> list[int]:
    """Largest-Triangle-Three-Buckets: the indices of at most ``max_points`` samples that keep
    a line chart's shape (peaks and dips survive, unlike with a stride).

    The first and last points are always kept; between them each bucket contributes the
    point that spans the largest triangle with the point kept before it and the mean of the
    next bucket (Steinarsson, 2013). Written out as the reference :func:`downsample` is
    tested against.
    """
    n = len(xs)
    if not _downsample_checked(xs, ys, max_points):
        return list(range(n))
    every = (n - 2) / (max_points - 2)
    kept = [0]
    a = 0
    for bucket in range(max_points - 2):
        start = int(bucket * every) + 1
        end = int((bucket + 1) * every) + 1
        next_end = min(int((bucket + 2) * every) + 1, n)
        span = next_end - end
        if span > 0:
            avg_x = sum(xs[end:next_end]) / span
            avg_y = sum(ys[end:next_end]) / span
        else:  # the last bucket: the final point is the one to aim at
            avg_x, avg_y = xs[n - 1], ys[n - 1]
        ax, ay = xs[a], ys[a]
        best, best_area = start, -1.0
        for i in range(start, end):
            # Twice the triangle's area; the factor does not change which point wins.
            area = abs((ax - avg_x) * (ys[i] - ay) - (ax - xs[i]) * (avg_y - ay))
            if area > best_area:
                best, best_area = i, area
        kept.append(best)
        a = best
    kept.append(n - 1)
    return kept
