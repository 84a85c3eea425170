"""Where the robot was when a measurement was taken: points placed on a run's samples.

A researcher's own measurement (a signal strength, a throughput) has a time and a value; the
run's samples say where the robot was at each control tick. :func:`place` gives each point
the robot's along-track position interpolated between the two samples around it — on the
rail unwrapped across laps, so that a point between 119.9 m and 0.1 m of a 120 m rail lies at
120.0 m, never at 60 m — and what held at that moment: the lap, the program segment, the
commanded and measured velocity, the GPS position when both samples had a fix, and the
nearer sample's grid cell.

Never across a gap: two samples are neighbours only when their sequence numbers follow each
other (and their times are less than ``MAX_STEP_S`` apart); a point between samples that are
not is "the robot's position unknown" (``GAP``). A point before the first sample or after the
last is kept and marked (``BEFORE``, ``AFTER``). A point at a sample's time is placed exactly
at that sample.

Pure numpy, no Django: the property tests (``tests/runs/test_placement.py``) hold it to
these rules over generated runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

# Samples further apart in time than this are not neighbours even when their sequence
# numbers follow (the agent's clock stepped): nothing is interpolated between them.
MAX_STEP_S: Final = 1.0

# Where a point is, in ``Placed.where``.
PLACED: Final = 0
BEFORE: Final = 1  # before the run's first sample
AFTER: Final = 2  # after its last
GAP: Final = 3  # between samples that are not neighbours: the position is unknown
WHERE_NAMES: Final = {PLACED: "placed", BEFORE: "before", AFTER: "after", GAP: "gap"}


@dataclass(frozen=True)
class Track:
    """A run's samples as placement reads them, in sequence order, one array per column
    (``NaN`` where a sample has no value: segment, lap, lat/lon without a fix)."""

    seq: np.ndarray
    t_s: np.ndarray
    track_m: np.ndarray
    segment: np.ndarray
    lap: np.ndarray
    commanded_velocity_mps: np.ndarray
    velocity_mps: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    grid_id: list[str | None]
    rail_length_m: float | None

    def __post_init__(self) -> None:
        n = len(self.seq)
        columns = (
            self.t_s,
            self.track_m,
            self.segment,
            self.lap,
            self.commanded_velocity_mps,
            self.velocity_mps,
            self.lat_deg,
            self.lon_deg,
        )
        if any(len(column) != n for column in columns) or len(self.grid_id) != n:
            raise ValueError("every column of a track has one value per sample")
        if n > 1 and not (np.all(np.diff(self.seq) > 0) and np.all(np.diff(self.t_s) >= 0)):
            raise ValueError("a track's samples are in sequence order, their times not falling")
        if self.rail_length_m is not None and not (
            np.isfinite(self.rail_length_m) and self.rail_length_m > 0
        ):
            raise ValueError(f"rail_length_m must be positive, got {self.rail_length_m!r}")

    def unwrapped_m(self) -> np.ndarray:
        """The along-track positions made continuous across laps (on a rail of known length:
        each step taken the short way round), from the first sample's position."""
        if self.rail_length_m is None or len(self.track_m) == 0:
            return self.track_m.astype(np.float64)
        length_m = self.rail_length_m
        track = self.track_m % length_m
        half_m = length_m / 2.0
        steps = (np.diff(track) + half_m) % length_m - half_m
        return np.cumsum(np.concatenate(([track[0]], steps)))

    def neighbours(self) -> np.ndarray:
        """For each pair of successive samples, whether they are neighbours (no gap)."""
        return (np.diff(self.seq) == 1) & (np.diff(self.t_s) <= MAX_STEP_S)


@dataclass(frozen=True)
class Placed:
    """The points placed, one value per point in each array (``NaN`` where not known)."""

    where: np.ndarray  # PLACED, BEFORE, AFTER or GAP
    track_m: np.ndarray  # in [0, rail length) on a rail of known length
    unwrapped_m: np.ndarray  # continuous across laps: the track's own count
    lap: np.ndarray
    segment: np.ndarray
    commanded_velocity_mps: np.ndarray
    velocity_mps: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    grid_id: list[str | None]
    # The nearer sample's sequence number (the point's row in the run's samples).
    sample_seq: np.ndarray


@dataclass(frozen=True)
class _Located:
    """Where each point falls: its ``where``, and for the placed ones (in the order of
    ``where == PLACED``) the samples either side and the fraction of the way between."""

    where: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    f: np.ndarray


def _locate(t: np.ndarray, track: Track) -> _Located:
    n_samples = len(track.seq)
    sample_t = track.t_s
    # i: the last sample at or before each point (-1 before the first).
    i = np.searchsorted(sample_t, t, side="right") - 1
    before, after = i < 0, t > sample_t[-1]
    at_sample = ~before & (t == sample_t[np.clip(i, 0, None)])
    inner = ~before & ~after & ~at_sample
    joined = np.zeros(len(t), dtype=bool)
    joined[inner] = track.neighbours()[i[inner]]
    where = np.full(len(t), GAP, dtype=np.int8)
    where[before], where[after] = BEFORE, AFTER
    where[at_sample | joined] = PLACED
    # Placed points: between sample lo and hi at fraction f (f = 0 at a sample's own time).
    placed = where == PLACED
    lo = np.clip(i, 0, n_samples - 1)[placed]
    hi = np.where(at_sample[placed], lo, np.minimum(lo + 1, n_samples - 1))
    span_s = sample_t[hi] - sample_t[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(span_s > 0, (t[placed] - sample_t[lo]) / span_s, 0.0)
    return _Located(where, lo, hi, f)


def place(times_s: np.ndarray, track: Track) -> Placed:
    """Each point's place on ``track`` at ``times_s`` (Unix seconds, on the base station's
    clock: a series's clock offset is added before). Points may come in any order."""
    t = np.asarray(times_s, dtype=np.float64)
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError("the points' times are one finite number each")
    n_points = len(t)
    unknown = np.full(n_points, np.nan)
    if len(track.seq) == 0:
        return Placed(
            where=np.full(n_points, GAP, dtype=np.int8),
            track_m=unknown.copy(),
            unwrapped_m=unknown.copy(),
            lap=unknown.copy(),
            segment=unknown.copy(),
            commanded_velocity_mps=unknown.copy(),
            velocity_mps=unknown.copy(),
            lat_deg=unknown.copy(),
            lon_deg=unknown.copy(),
            grid_id=[None] * n_points,
            sample_seq=unknown.copy(),
        )
    located = _locate(t, track)
    placed, lo, hi, f = located.where == PLACED, located.lo, located.hi, located.f

    def between(column: np.ndarray) -> np.ndarray:
        out = unknown.copy()
        out[placed] = column[lo] + f * (column[hi] - column[lo])
        return out

    def held(column: np.ndarray) -> np.ndarray:
        out = unknown.copy()
        out[placed] = column[lo]  # what held from the earlier sample on: a command, a segment
        return out

    unwrapped = between(track.unwrapped_m())
    on_rail = unwrapped % track.rail_length_m if track.rail_length_m else unwrapped.copy()
    nearer = np.where(f < 0.5, lo, hi)
    grid: list[str | None] = [None] * n_points
    for k, sample in zip(np.flatnonzero(placed), nearer, strict=True):
        grid[k] = track.grid_id[sample]
    sample_seq = unknown.copy()
    sample_seq[placed] = track.seq[nearer]
    return Placed(
        where=located.where,
        track_m=on_rail,
        unwrapped_m=unwrapped,
        lap=held(track.lap),
        segment=held(track.segment),
        commanded_velocity_mps=held(track.commanded_velocity_mps),
        velocity_mps=between(track.velocity_mps),
        # The GPS position only between two fixes (NaN on either side stays NaN).
        lat_deg=between(track.lat_deg),
        lon_deg=between(track.lon_deg),
        grid_id=grid,
        sample_seq=sample_seq,
    )
