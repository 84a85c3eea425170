"""What a measurement series says once placed on the run's path: the numbers the run page,
the API and the package show, computed once when the points or the clock offset change.

Per value column: how many points fell where (placed on the path, before or after the run's
samples, in a gap of them), the statistics of the placed ones, the binned mean and spread per
metre of track, per grid cell statistics, and two downsampled views (value against time with
the robot's velocity, value against position). Pure numpy, no Django.
"""

from __future__ import annotations

import re
from typing import Any, Final

import numpy as np

from portal.runs.downsampling import downsample
from portal.runs.placement import AFTER, BEFORE, GAP, PLACED, Placed

# The downsampled views' sizes: enough for a chart as wide as a laptop's screen.
LINE_MAX_POINTS: Final = 1000
SCATTER_MAX_POINTS: Final = 2000
# The bins along the track.
BIN_M: Final = 1.0


def _stats(values: np.ndarray) -> dict[str, float | int | None]:
    if len(values) == 0:
        return {"count": 0, "mean": None, "min": None, "max": None, "std": None}
    return {
        "count": len(values),
        "mean": float(np.mean(values)),
        "min": float(np.min(values)),
        "max": float(np.max(values)),
        "std": float(np.std(values)),
    }


def _grouped(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, ...]:
    """For each distinct key: the key, count, mean, standard deviation, min and max."""
    distinct, inverse = np.unique(keys, return_inverse=True)
    counts = np.bincount(inverse)
    sums = np.bincount(inverse, weights=values)
    means = sums / counts
    squares = np.bincount(inverse, weights=(values - means[inverse]) ** 2)
    lows = np.full(len(distinct), np.inf)
    highs = np.full(len(distinct), -np.inf)
    np.minimum.at(lows, inverse, values)
    np.maximum.at(highs, inverse, values)
    return distinct, counts, means, np.sqrt(squares / counts), lows, highs


def _cell_order(cell: str) -> tuple[str, int, str]:
    match = re.fullmatch(r"([A-Za-z]+)(\d+)", cell)
    return (match.group(1), int(match.group(2)), "") if match else (cell, 0, cell)


def _by_cell(cells: list[str | None], placed: np.ndarray, values: np.ndarray) -> list[dict]:
    keys = np.array([cells[i] or "" for i in np.flatnonzero(placed)], dtype=object)
    known = keys != ""
    if not known.any():
        return []
    distinct, counts, means, stds, lows, highs = _grouped(
        keys[known].astype(str), values[placed][known]
    )
    rows = [
        {
            "cell": str(cell),
            "count": int(count),
            "mean": float(mean),
            "min": float(low),
            "max": float(high),
            "std": float(std),
        }
        for cell, count, mean, std, low, high in zip(
            distinct, counts, means, stds, lows, highs, strict=True
        )
    ]
    return sorted(rows, key=lambda row: _cell_order(str(row["cell"])))


def _by_metre(track_m: np.ndarray, values: np.ndarray) -> list[list[float | int]]:
    if len(values) == 0:
        return []
    bins, counts, means, stds, _, _ = _grouped(np.floor(track_m / BIN_M).astype(np.int64), values)
    return [
        [float(b * BIN_M), int(c), float(m), float(s)]
        for b, c, m, s in zip(bins, counts, means, stds, strict=True)
    ]


def _rounded(values: np.ndarray, digits: int) -> list[float | None]:
    return [None if np.isnan(v) else round(float(v), digits) for v in values]


def column_summary(
    times_s: np.ndarray, values: np.ndarray, placed: Placed, *, start_s: float
) -> dict[str, Any]:
    """One value column's summary. ``times_s`` on the base station's clock (the offset
    added), in order; ``placed`` their places; ``start_s`` the run's start (the views'
    times are seconds from it)."""
    where = placed.where
    on_path = where == PLACED
    on_path_values = values[on_path]
    line = downsample(times_s, values, LINE_MAX_POINTS) if len(values) else []
    step = max(1, int(np.ceil(on_path.sum() / SCATTER_MAX_POINTS)))
    scatter = np.flatnonzero(on_path)[::step]
    return {
        "points": len(values),
        "where": {
            "placed": int(on_path.sum()),
            "before": int((where == BEFORE).sum()),
            "after": int((where == AFTER).sum()),
            "gap": int((where == GAP).sum()),
        },
        "stats": _stats(on_path_values),
        "by_metre": _by_metre(placed.track_m[on_path], on_path_values),
        "by_cell": _by_cell(placed.grid_id, on_path, values),
        "line": {
            "t_s": _rounded(times_s[line] - start_s, 4),
            "value": _rounded(values[line], 6),
            "velocity_mps": _rounded(placed.velocity_mps[line], 4),
        },
        "scatter": {
            "track_m": _rounded(placed.track_m[scatter], 3),
            "value": _rounded(values[scatter], 6),
        },
    }
