"""What a run's samples say: per-segment statistics, laps, passes at a position, gaps.

Pure functions over plain rows, so they are tested without a database and run the same in
the web page, the REST API and the benchmarks. Laps and passes come from the along-track
position unwrapped the same way the base station does it (``basestation.telemetry.laps``,
plain Python with no agent behind it), so the portal and the agent count the same laps.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from basestation.telemetry.laps import LapCounter, Pass, wrap_delta_m
from portal.runs.downsampling import downsample

# RTK fixed, in the GGA sentence's fix-quality numbering.
RTK_FIXED = 4


class SampleRow(NamedTuple):
    """The columns of one stored sample the analysis reads; ``t_s`` is seconds since the
    run's first sample, velocities are speeds (never negative) with ``direction`` apart."""

    seq: int
    t_s: float
    segment: int | None
    commanded_velocity_mps: float
    velocity_mps: float
    direction: str
    battery_v: float
    track_m: float
    fix_quality: int | None


def signed(speed_mps: float, direction: str) -> float:
    """Clockwise positive: a reversal shows as crossing zero."""
    return -speed_mps if direction == "ccw" else speed_mps


@dataclass
class SegmentStats:
    """One program segment as the robot drove it."""

    index: int  # 0-based, as in the program
    commanded_mps: float  # signed
    samples: int = 0
    start_s: float = 0.0
    end_s: float = 0.0
    distance_m: float = 0.0
    mean_mps: float = 0.0  # signed, measured
    min_mps: float = math.inf
    max_mps: float = -math.inf
    std_mps: float = 0.0
    mean_abs_error_mps: float = 0.0  # |measured - commanded|, ramps included
    battery_start_v: float | None = None
    battery_end_v: float | None = None
    battery_min_v: float | None = None
    rtk_fixed_share: float = 0.0
    _sum_sq: float = field(default=0.0, repr=False)
    _fixed: int = field(default=0, repr=False)

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    def add(self, row: SampleRow, measured_mps: float, moved_m: float) -> None:
        if self.samples == 0:
            self.start_s = row.t_s
            self.battery_start_v = row.battery_v
            self.battery_min_v = row.battery_v
        self.samples += 1
        self.end_s = row.t_s
        self.distance_m += moved_m
        # Running sums; the mean and spread are finished in ``close``.
        self.mean_mps += measured_mps
        self._sum_sq += measured_mps * measured_mps
        self.min_mps = min(self.min_mps, measured_mps)
        self.max_mps = max(self.max_mps, measured_mps)
        self.mean_abs_error_mps += abs(measured_mps - self.commanded_mps)
        self.battery_end_v = row.battery_v
        if self.battery_min_v is None or row.battery_v < self.battery_min_v:
            self.battery_min_v = row.battery_v
        self._fixed += row.fix_quality == RTK_FIXED

    def close(self) -> None:
        n = self.samples
        if n == 0:
            self.min_mps = self.max_mps = 0.0
            return
        total = self.mean_mps
        self.mean_mps = total / n
        self.std_mps = math.sqrt(max(0.0, self._sum_sq / n - self.mean_mps**2))
        self.mean_abs_error_mps /= n
        self.rtk_fixed_share = self._fixed / n


@dataclass(frozen=True)
class Lap:
    """A whole lap of path completed (whatever the direction), timed by interpolation."""

    index: int
    start_s: float
    end_s: float
    length_m: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s

    @property
    def mean_speed_mps(self) -> float:
        return self.length_m / self.duration_s if self.duration_s > 0 else 0.0


@dataclass(frozen=True)
class Gap:
    """Sequence numbers the base station never delivered: ``first_seq`` to ``last_seq``."""

    first_seq: int
    last_seq: int

    @property
    def missing(self) -> int:
        return self.last_seq - self.first_seq + 1


@dataclass
class RunAnalysis:
    samples: int = 0
    duration_s: float = 0.0
    rail_length_m: float | None = None
    distance_m: float | None = None
    net_laps: int | None = None
    pass_at_m: float | None = None
    segments: list[SegmentStats] = field(default_factory=list)
    laps: list[Lap] = field(default_factory=list)
    passes: list[Pass] = field(default_factory=list)
    gaps: list[Gap] = field(default_factory=list)
    outside_program: int = 0  # samples taken before the first or after the last segment

    @property
    def missing(self) -> int:
        return sum(g.missing for g in self.gaps)

    @property
    def mean_speed_mps(self) -> float | None:
        if self.distance_m is None or self.duration_s <= 0:
            return None
        return self.distance_m / self.duration_s


def analyse(
    rows: Iterable[SampleRow],
    *,
    segments: Sequence[dict[str, object]],
    rail_length_m: float | None,
    pass_at_m: float | None = None,
) -> RunAnalysis:
    """One pass over a run's samples, in sequence order.

    Without the rail length (a run collected from an agent that did not report it) the
    along-track position cannot be unwrapped: distance, laps and passes are then ``None`` or
    empty, and everything else is still computed.
    """
    _check_rail(rail_length_m, pass_at_m)
    result = RunAnalysis(rail_length_m=rail_length_m, pass_at_m=pass_at_m)
    result.segments = [
        SegmentStats(
            index=i,
            commanded_mps=signed(float(str(s["velocity_mps"])), str(s["direction"])),
        )
        for i, s in enumerate(segments)
    ]
    counter = LapCounter(rail_length_m, pass_at_m=pass_at_m) if rail_length_m is not None else None
    last_seq: int | None = None
    first_t_s = last_t_s = 0.0
    for row in rows:
        if last_seq is None:
            first_t_s = last_t_s = row.t_s
        elif row.seq > last_seq + 1:
            result.gaps.append(Gap(last_seq + 1, row.seq - 1))
        result.samples += 1
        moved_m = 0.0
        if counter is not None:
            before_m = counter.distance_m
            before_laps = counter.laps_travelled
            counter.update(row.track_m, row.t_s, row.velocity_mps)
            moved_m = counter.distance_m - before_m
            if counter.laps_travelled > before_laps:
                lap_end_m = counter.length_m * counter.laps_travelled
                fraction = (lap_end_m - before_m) / moved_m if moved_m > 0 else 1.0
                end_s = last_t_s + fraction * (row.t_s - last_t_s)
                start_s = result.laps[-1].end_s if result.laps else first_t_s
                result.laps.append(Lap(len(result.laps) + 1, start_s, end_s, counter.length_m))
        last_seq = row.seq
        last_t_s = row.t_s
        if row.segment is None or not 0 <= row.segment < len(result.segments):
            result.outside_program += 1
            continue
        result.segments[row.segment].add(row, signed(row.velocity_mps, row.direction), moved_m)
    for stats in result.segments:
        stats.close()
    result.duration_s = last_t_s - first_t_s
    if counter is not None:
        result.distance_m = counter.distance_m
        result.net_laps = counter.laps
        result.passes = counter.passes
    return result


class SeriesCollector:
    """Keeps the columns the run page charts, sample by sample, and downsamples them."""

    def __init__(
        self, segments: Sequence[dict[str, object]], rail_length_m: float | None = None
    ) -> None:
        # Unwrapped, the position is a continuous line: no jump of a whole rail each time the
        # robot crosses the origin, and laps show as steady climbs.
        self.rail_length_m = rail_length_m
        # The sample's direction is the robot's; the command's is the segment's (they differ
        # while the robot slows down to reverse).
        self.segment_sign = [-1.0 if s["direction"] == "ccw" else 1.0 for s in segments]
        self.t_s: list[float] = []
        self.measured_mps: list[float] = []
        self.battery_v: list[float] = []
        self.track_m: list[float] = []
        self._last_track_m = 0.0
        # The command is a step function: its changes describe it exactly, in few points.
        self.commanded: list[tuple[float, float]] = []

    def take(self, row: SampleRow) -> SampleRow:
        self.t_s.append(row.t_s)
        self.measured_mps.append(signed(row.velocity_mps, row.direction))
        self.battery_v.append(row.battery_v)
        if self.rail_length_m is not None and self.track_m:
            step_m = wrap_delta_m(row.track_m - self._last_track_m, self.rail_length_m)
            self.track_m.append(self.track_m[-1] + step_m)
        else:
            self.track_m.append(row.track_m)
        self._last_track_m = row.track_m
        sign = 1.0
        if row.segment is not None and 0 <= row.segment < len(self.segment_sign):
            sign = self.segment_sign[row.segment]
        commanded = sign * row.commanded_velocity_mps
        if not self.commanded or self.commanded[-1][1] != commanded:
            self.commanded.append((row.t_s, commanded))
        return row

    def series(self, max_points: int) -> dict[str, dict[str, list[float]]]:
        """Each chart line as ``{"t": [...], "y": [...]}``, at most ``max_points`` long."""
        out: dict[str, dict[str, list[float]]] = {}
        for name, ys, digits in (
            ("measured_mps", self.measured_mps, 4),
            ("battery_v", self.battery_v, 3),
            ("track_m", self.track_m, 3),
        ):
            keep = downsample(self.t_s, ys, max_points)
            out[name] = {
                "t": [round(self.t_s[i], 3) for i in keep],
                "y": [round(ys[i], digits) for i in keep],
            }
        steps = list(self.commanded)
        if self.t_s and steps and steps[-1][0] != self.t_s[-1]:
            steps.append((self.t_s[-1], steps[-1][1]))  # draw the last step to the end
        if len(steps) > max_points:
            keep = downsample([t for t, _ in steps], [v for _, v in steps], max_points)
            steps = [steps[i] for i in keep]
        out["commanded_mps"] = {"t": [round(t, 3) for t, _ in steps], "y": [v for _, v in steps]}
        return out


# --- The same, a column at a time ---------------------------------------------------------
#
# A one-hour run is 72 000 samples: the loop above, one Python call after another per sample,
# takes about a second; numpy over whole columns takes a few hundredths. ``analyse`` and
# ``SeriesCollector`` stay as the reference the tests hold these to (same additions in the
# same order, so the same floats).


@dataclass(frozen=True)
class SampleColumns:
    """A run's samples in ``seq`` order, one array per column; None is NaN in ``segment``
    and ``fix_quality``, and ``ccw`` is True where the direction is counter-clockwise."""

    seq: np.ndarray
    t_s: np.ndarray
    segment: np.ndarray
    commanded_velocity_mps: np.ndarray
    velocity_mps: np.ndarray
    ccw: np.ndarray
    battery_v: np.ndarray
    track_m: np.ndarray
    fix_quality: np.ndarray

    @classmethod
    def from_rows(cls, rows: Iterable[SampleRow]) -> SampleColumns:
        listed = list(rows)
        if not listed:
            return cls.from_lists(*([] for _ in SampleRow._fields))
        return cls.from_lists(*(list(c) for c in zip(*listed, strict=True)))

    @classmethod
    def from_lists(
        cls,
        seq: Sequence[int],
        t_s: Sequence[float],
        segment: Sequence[int | None],
        commanded_velocity_mps: Sequence[float],
        velocity_mps: Sequence[float],
        direction: Sequence[str],
        battery_v: Sequence[float],
        track_m: Sequence[float],
        fix_quality: Sequence[int | None],
    ) -> SampleColumns:
        """From the columns of :class:`SampleRow`, as lists (None allowed where it is)."""
        return cls(
            seq=np.asarray(seq, dtype=np.int64),
            t_s=np.asarray(t_s, dtype=np.float64),
            segment=np.asarray(segment, dtype=np.float64),
            commanded_velocity_mps=np.asarray(commanded_velocity_mps, dtype=np.float64),
            velocity_mps=np.asarray(velocity_mps, dtype=np.float64),
            ccw=np.asarray(direction, dtype=object) == "ccw",
            battery_v=np.asarray(battery_v, dtype=np.float64),
            track_m=np.asarray(track_m, dtype=np.float64),
            fix_quality=np.asarray(fix_quality, dtype=np.float64),
        )

    def __len__(self) -> int:
        return len(self.seq)

    def signed_mps(self) -> np.ndarray:
        return np.where(self.ccw, -self.velocity_mps, self.velocity_mps)

    def segment_index(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """Which rows lie in one of ``count`` program segments, and their segment."""
        inside = ~np.isnan(self.segment) & (self.segment >= 0) & (self.segment < count)
        return inside, self.segment[inside].astype(np.int64)


def _wrap(delta_m: np.ndarray, length_m: float) -> np.ndarray:
    """:func:`wrap_delta_m` over an array (numpy's % is Python's for floats)."""
    half_m = length_m / 2.0
    return (delta_m + half_m) % length_m - half_m


def _check_rail(rail_length_m: float | None, pass_at_m: float | None) -> None:
    if rail_length_m is not None and not (math.isfinite(rail_length_m) and rail_length_m > 0):
        raise ValueError(f"rail_length_m must be a positive number, got {rail_length_m!r}")
    if pass_at_m is not None:
        if rail_length_m is None:
            raise ValueError("Passes need the rail length, which this run does not have.")
        if not (math.isfinite(pass_at_m) and 0 <= pass_at_m < rail_length_m):
            raise ValueError(f"The position must be from 0 up to {rail_length_m:g} m.")


def analyse_columns(
    columns: SampleColumns,
    *,
    segments: Sequence[dict[str, object]],
    rail_length_m: float | None,
    pass_at_m: float | None = None,
) -> RunAnalysis:
    """What :func:`analyse` computes, over whole columns."""
    _check_rail(rail_length_m, pass_at_m)
    n = len(columns)
    if n == 0:
        return analyse([], segments=segments, rail_length_m=rail_length_m, pass_at_m=pass_at_m)
    result = RunAnalysis(rail_length_m=rail_length_m, pass_at_m=pass_at_m, samples=n)
    seq, t = columns.seq, columns.t_s
    for i in np.flatnonzero(seq[1:] > seq[:-1] + 1):
        result.gaps.append(Gap(int(seq[i]) + 1, int(seq[i + 1]) - 1))
    result.duration_s = float(t[-1] - t[0])
    # What each sample added to the distance travelled (none without the rail length).
    moved = np.zeros(n)
    if rail_length_m is not None:
        moved = _laps_and_passes(columns, rail_length_m, pass_at_m, result)
    result.segments = [
        SegmentStats(
            index=i,
            commanded_mps=signed(float(str(s["velocity_mps"])), str(s["direction"])),
        )
        for i, s in enumerate(segments)
    ]
    inside, index = columns.segment_index(len(segments))
    result.outside_program = int(n - np.count_nonzero(inside))
    if index.size:
        _segment_stats(columns, inside, index, moved, result.segments)
    for stats in result.segments:
        stats.close()
    return result


def _laps_and_passes(
    columns: SampleColumns, length_m: float, pass_at_m: float | None, result: RunAnalysis
) -> np.ndarray:
    """Distance, laps and passes as :class:`LapCounter` finds them (the distance from the
    reported speed, the laps of path from that distance, net laps and passes from the
    position); the distance each sample added."""
    t, track = columns.t_s, columns.track_m % length_m
    steps = _wrap(np.diff(track), length_m)
    unwrapped = np.cumsum(np.concatenate(([track[0]], steps)))
    # The reported speed held from each sample to the next, as LapCounter counts the path:
    # the position's jitter is not movement.
    step_moved = np.abs(columns.velocity_mps[:-1]) * np.maximum(np.diff(t), 0.0)
    travelled = np.cumsum(np.concatenate(([0.0], step_moved)))
    moved = np.concatenate(([0.0], np.diff(travelled)))
    result.distance_m = float(travelled[-1])
    result.net_laps = int((unwrapped[-1] - unwrapped[0]) / length_m)
    whole = np.floor_divide(travelled, length_m)
    first_t_s = float(t[0])
    for i in np.flatnonzero(whole[1:] > whole[:-1]) + 1:
        lap_end_m = length_m * int(whole[i])
        fraction = (lap_end_m - travelled[i - 1]) / moved[i] if moved[i] > 0 else 1.0
        end_s = float(t[i - 1] + fraction * (t[i] - t[i - 1]))
        start_s = result.laps[-1].end_s if result.laps else first_t_s
        result.laps.append(Lap(len(result.laps) + 1, start_s, end_s, length_m))
    if pass_at_m is not None:
        rail = RailTrack(t, unwrapped, columns.velocity_mps, length_m)
        result.passes = passes_at(rail, pass_at_m, rail_length_m=length_m)
    return moved


@dataclass(frozen=True)
class RailTrack:
    """What passes at a position are found from: the sample times, the unwrapped along-track
    positions and the speeds. Kept with a run's cached report, so that passes at any
    position cost one pass over three arrays, not a new report."""

    t_s: np.ndarray
    unwrapped_m: np.ndarray
    velocity_mps: np.ndarray
    length_m: float


def rail_track(columns: SampleColumns, rail_length_m: float | None) -> RailTrack | None:
    """The run's track for :func:`passes_at`; None without samples or the rail length."""
    if rail_length_m is None or len(columns) == 0:
        return None
    _check_rail(rail_length_m, None)
    track = columns.track_m % rail_length_m
    steps = _wrap(np.diff(track), rail_length_m)
    unwrapped = np.cumsum(np.concatenate(([track[0]], steps)))
    return RailTrack(columns.t_s, unwrapped, columns.velocity_mps, rail_length_m)


def passes_at(
    track: RailTrack | None, pass_at_m: float, *, rail_length_m: float | None
) -> list[Pass]:
    """Each crossing of ``pass_at_m``, interpolated between the samples either side
    (``ValueError`` for a position off the rail, or without the rail length)."""
    _check_rail(rail_length_m, pass_at_m)
    if track is None:
        return []
    t, unwrapped, speed, length_m = track.t_s, track.unwrapped_m, track.velocity_mps, track.length_m
    at_m = pass_at_m % length_m
    cells = np.floor((unwrapped - at_m) / length_m)
    passes: list[Pass] = []
    for i in np.flatnonzero(cells[1:] != cells[:-1]) + 1:
        before_m, after_m = float(unwrapped[i - 1]), float(unwrapped[i])
        if after_m == before_m:
            continue
        clockwise = after_m > before_m
        crossing_m = at_m + length_m * int(cells[i] if clockwise else cells[i - 1])
        fraction = (crossing_m - before_m) / (after_m - before_m)
        dt_s = float(t[i] - t[i - 1])
        speed_mps = float(speed[i - 1]) + fraction * (float(speed[i]) - float(speed[i - 1]))
        passes.append(
            Pass(
                index=len(passes) + 1,
                t_s=float(t[i - 1]) + fraction * dt_s,
                direction="cw" if clockwise else "ccw",
                velocity_mps=abs(speed_mps),
            )
        )
    return passes


def _segment_stats(
    columns: SampleColumns,
    inside: np.ndarray,
    index: np.ndarray,
    moved: np.ndarray,
    stats: list[SegmentStats],
) -> None:
    """Each segment's sums, extremes and ends, as :meth:`SegmentStats.add` keeps them
    (``bincount`` adds in row order, as the loop does)."""
    count = len(stats)
    measured = columns.signed_mps()[inside]
    commanded = np.array([s.commanded_mps for s in stats])[index]
    t, battery = columns.t_s[inside], columns.battery_v[inside]
    samples = np.bincount(index, minlength=count)
    sums = {
        "distance_m": np.bincount(index, moved[inside], count),
        "mean_mps": np.bincount(index, measured, count),
        "_sum_sq": np.bincount(index, measured * measured, count),
        "mean_abs_error_mps": np.bincount(index, np.abs(measured - commanded), count),
    }
    fixed = np.bincount(index, columns.fix_quality[inside] == RTK_FIXED, count)
    present, first = np.unique(index, return_index=True)
    last = len(index) - 1 - np.unique(index[::-1], return_index=True)[1]
    order = np.argsort(index, kind="stable")
    bounds = np.searchsorted(index[order], present)
    for k, (segment, i, j) in enumerate(zip(present, first, last, strict=True)):
        s = stats[int(segment)]
        rows = order[bounds[k] : bounds[k] + samples[segment]]
        s.samples = int(samples[segment])
        s.start_s, s.end_s = float(t[i]), float(t[j])
        s.distance_m = float(sums["distance_m"][segment])
        s.mean_mps = float(sums["mean_mps"][segment])
        s._sum_sq = float(sums["_sum_sq"][segment])
        s.mean_abs_error_mps = float(sums["mean_abs_error_mps"][segment])
        s.min_mps, s.max_mps = float(measured[rows].min()), float(measured[rows].max())
        s.battery_start_v, s.battery_end_v = float(battery[i]), float(battery[j])
        s.battery_min_v = float(battery[rows].min())
        s._fixed = int(fixed[segment])


def chart_series(
    columns: SampleColumns,
    *,
    segments: Sequence[dict[str, object]],
    rail_length_m: float | None,
    max_points: int,
) -> dict[str, dict[str, list[float]]]:
    """What :meth:`SeriesCollector.series` gives, over whole columns."""
    t = columns.t_s
    track = columns.track_m
    if rail_length_m is not None and len(track):
        steps = _wrap(np.diff(track), rail_length_m)
        track = np.cumsum(np.concatenate(([track[0]], steps)))
    out: dict[str, dict[str, list[float]]] = {}
    for name, ys, digits in (
        ("measured_mps", columns.signed_mps(), 4),
        ("battery_v", columns.battery_v, 3),
        ("track_m", track, 3),
    ):
        keep = downsample(t, ys, max_points)
        # Python's round, as the page always had it (numpy's differs in the last digit).
        out[name] = {
            "t": [round(x, 3) for x in t[keep].tolist()],
            "y": [round(y, digits) for y in ys[keep].tolist()],
        }
    sign = np.ones(len(columns))
    inside, index = columns.segment_index(len(segments))
    segment_sign = np.array([-1.0 if s["direction"] == "ccw" else 1.0 for s in segments])
    sign[inside] = segment_sign[index]
    commanded = sign * columns.commanded_velocity_mps
    changes = np.flatnonzero(commanded[1:] != commanded[:-1]) + 1
    where = np.concatenate(([0], changes)) if len(commanded) else changes
    steps_t, steps_v = t[where].tolist(), commanded[where].tolist()
    if len(t) and steps_t and steps_t[-1] != t[-1]:
        steps_t.append(float(t[-1]))  # draw the last step to the end
        steps_v.append(steps_v[-1])
    if len(steps_t) > max_points:
        keep = downsample(steps_t, steps_v, max_points)
        steps_t, steps_v = [steps_t[i] for i in keep], [steps_v[i] for i in keep]
    out["commanded_mps"] = {"t": [round(x, 3) for x in steps_t], "y": steps_v}
    return out
