"""A run's samples turned into segment statistics, laps, passes, gaps and chart series."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from portal.runs.analysis import (
    SampleColumns,
    SeriesCollector,
    analyse,
    analyse_columns,
    chart_series,
)
from portal.runs.downsampling import downsample, lttb
from tests.runs.driving import HZ, RAIL_M, drive, segments


def test_laps_are_timed_where_the_robot_completes_each_one():
    program = [(2.0, "cw", 120.0)]
    result = analyse(drive(program), segments=segments(program), rail_length_m=RAIL_M)
    assert result.samples == 2400
    assert result.distance_m == pytest.approx(2.0 * (120.0 - 1 / HZ))
    assert result.net_laps == 2
    assert [lap.index for lap in result.laps] == [1, 2]
    assert [lap.end_s for lap in result.laps] == pytest.approx([50.0, 100.0])
    assert [lap.duration_s for lap in result.laps] == pytest.approx([50.0, 50.0])
    assert [lap.mean_speed_mps for lap in result.laps] == pytest.approx([2.0, 2.0])
    assert result.mean_speed_mps == pytest.approx(2.0)


def test_passes_at_a_position_have_time_direction_and_velocity():
    # 60 s clockwise at 2 m/s from 10 m, then 60 s counter-clockwise at 1 m/s.
    program = [(2.0, "cw", 60.0), (1.0, "ccw", 60.0)]
    result = analyse(
        drive(program), segments=segments(program), rail_length_m=RAIL_M, pass_at_m=60.0
    )
    # Unwrapped, the robot goes 10 → 130 m (t = 0…60 s), then back 130 → 70 m (…120 s):
    # it passes 60 m once, at t = 25 s, and never comes back to it.
    assert [(p.index, p.direction) for p in result.passes] == [(1, "cw")]
    assert result.passes[0].t_s == pytest.approx(25.0)
    assert result.passes[0].velocity_mps == pytest.approx(2.0)

    back = analyse(drive(program), segments=segments(program), rail_length_m=RAIL_M, pass_at_m=20.0)
    # cw passes 20 m at t=5 s and 120 m (20 + one lap) at t=55 s; ccw from 130 m passes
    # 120 m at t=70 s.
    assert [(p.direction, round(p.t_s, 3)) for p in back.passes] == [
        ("cw", 5.0),
        ("cw", 55.0),
        ("ccw", 70.0),
    ]
    assert back.passes[-1].velocity_mps == pytest.approx(1.0)


def test_segment_statistics_follow_the_program():
    program = [(2.0, "cw", 30.0), (0.5, "ccw", 20.0)]
    result = analyse(drive(program), segments=segments(program), rail_length_m=RAIL_M)
    first, second = result.segments
    assert (first.samples, second.samples) == (600, 400)
    assert first.commanded_mps == 2.0
    assert second.commanded_mps == -0.5
    assert first.mean_mps == pytest.approx(2.0)
    assert second.mean_mps == pytest.approx(-0.5)
    assert (second.min_mps, second.max_mps) == (-0.5, -0.5)
    assert first.std_mps == pytest.approx(0.0, abs=1e-6)
    assert first.mean_abs_error_mps == pytest.approx(0.0)
    assert first.duration_s == pytest.approx(30.0 - 1 / HZ)
    # Each segment's distance is what it moved from the previous sample, so the step into
    # the second segment (still at 2 m/s) counts in the second.
    assert first.distance_m + second.distance_m == pytest.approx(result.distance_m)
    assert first.distance_m == pytest.approx(2.0 * (30.0 - 1 / HZ))
    assert first.battery_start_v == 60.0
    assert first.battery_end_v == pytest.approx(60.0 - (30.0 - 1 / HZ) / 100.0)
    assert second.battery_min_v == second.battery_end_v
    assert first.rtk_fixed_share == pytest.approx(0.75)


def test_missing_sequence_numbers_are_reported_as_gaps():
    program = [(1.0, "cw", 10.0)]
    rows = drive(program, skip=frozenset({5, 6, 7, 100}))
    result = analyse(rows, segments=segments(program), rail_length_m=RAIL_M)
    assert [(g.first_seq, g.last_seq) for g in result.gaps] == [(5, 7), (100, 100)]
    assert result.missing == 4
    assert result.samples == 196


def test_without_the_rail_length_everything_but_laps_and_passes_is_computed():
    program = [(1.0, "cw", 10.0)]
    result = analyse(drive(program), segments=segments(program), rail_length_m=None)
    assert result.distance_m is None
    assert result.net_laps is None
    assert result.laps == []
    assert result.passes == []
    assert result.segments[0].mean_mps == pytest.approx(1.0)
    with pytest.raises(ValueError, match="rail length"):
        analyse([], segments=[], rail_length_m=None, pass_at_m=3.0)


@pytest.mark.parametrize("position_m", [-1.0, RAIL_M, 1e9, math.nan, math.inf])
def test_a_position_off_the_rail_is_refused(position_m):
    with pytest.raises(ValueError, match="from 0 up to 100 m"):
        analyse([], segments=[], rail_length_m=RAIL_M, pass_at_m=position_m)


@pytest.mark.parametrize("length_m", [0.0, -3.0, math.nan])
def test_a_nonsense_rail_length_is_refused(length_m):
    with pytest.raises(ValueError, match="rail_length_m"):
        analyse([], segments=[], rail_length_m=length_m)


def test_samples_outside_the_program_are_counted_apart():
    program = [(1.0, "cw", 1.0)]
    rows = drive(program)
    rows[0] = rows[0]._replace(segment=None)
    rows[1] = rows[1]._replace(segment=7)
    result = analyse(rows, segments=segments(program), rail_length_m=RAIL_M)
    assert result.outside_program == 2
    assert result.segments[0].samples == 18


def test_an_empty_run_has_an_empty_analysis():
    result = analyse([], segments=segments([(1.0, "cw", 5.0)]), rail_length_m=RAIL_M)
    assert (result.samples, result.duration_s, result.distance_m) == (0, 0.0, 0.0)
    assert result.segments[0].samples == 0
    assert result.mean_speed_mps is None


# -- downsampling -------------------------------------------------------------------------------


# ``lttb`` is the algorithm written out; ``downsample`` (compiled) is what the pages use.
DOWNSAMPLERS = pytest.mark.parametrize("downsampler", [lttb, downsample], ids=lambda f: f.__name__)


@DOWNSAMPLERS
@settings(max_examples=200, deadline=None)
@given(
    ys=st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=0, max_size=400),
    max_points=st.integers(3, 120),
)
def test_lttb_keeps_at_most_max_points_in_order_with_both_ends(downsampler, ys, max_points):
    xs = [float(i) for i in range(len(ys))]
    kept = downsampler(xs, ys, max_points)
    assert len(kept) == min(len(ys), max_points)
    assert kept == sorted(set(kept))
    if ys:
        assert kept[0] == 0
        assert kept[-1] == len(ys) - 1


@settings(max_examples=200, deadline=None)
@given(
    ys=st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=0, max_size=400),
    max_points=st.integers(3, 120),
)
def test_the_compiled_downsampling_keeps_in_each_bucket_a_point_lttb_would(ys, max_points):
    """The same buckets, and in each a point spanning the largest triangle with the point kept
    before it. Where two points span the same triangle (a tie, to rounding), either is right:
    the compiled code may break it the other way, and the rest follows from its pick."""
    xs = [i / HZ for i in range(len(ys))]
    kept = downsample(xs, ys, max_points)
    reference = lttb(xs, ys, max_points)
    assert len(kept) == len(reference)
    if len(kept) == len(ys):
        assert kept == reference
        return
    n = len(ys)
    every = (n - 2) / (max_points - 2)
    scale = max(1.0, max(abs(y) for y in ys)) * (xs[-1] - xs[0] + 1.0)
    for bucket in range(max_points - 2):
        start, end = int(bucket * every) + 1, int((bucket + 1) * every) + 1
        next_end = min(int((bucket + 2) * every) + 1, n)
        if next_end > end:
            avg_x = sum(xs[end:next_end]) / (next_end - end)
            avg_y = sum(ys[end:next_end]) / (next_end - end)
        else:
            avg_x, avg_y = xs[-1], ys[-1]
        a = kept[bucket]

        def area(i: int, a: int = a, avg_x: float = avg_x, avg_y: float = avg_y) -> float:
            return abs((xs[a] - avg_x) * (ys[i] - ys[a]) - (xs[a] - xs[i]) * (avg_y - ys[a]))

        pick = kept[bucket + 1]
        assert start <= pick < end
        assert area(pick) >= max(area(i) for i in range(start, end)) - 1e-9 * scale


def test_with_jittered_times_the_compiled_downsampling_keeps_nearly_the_same_points():
    rng = random.Random(7)
    n = 20_000
    # Ticks as the agent records them: 20 Hz with a little lateness each.
    xs = [i / HZ + rng.uniform(0.0, 0.002) for i in range(n)]
    ys = [math.sin(i / 50) + rng.uniform(0.0, 0.1) for i in range(n)]
    reference, compiled = lttb(xs, ys, 2000), downsample(xs, ys, 2000)
    assert len(compiled) == len(reference)
    # Where they differ is which of two near-equal triangles wins (rounding).
    assert sum(a == b for a, b in zip(reference, compiled, strict=True)) >= 0.95 * len(reference)


@DOWNSAMPLERS
def test_lttb_keeps_a_spike_that_a_stride_would_drop(downsampler):
    n = 72_000
    xs = [i / HZ for i in range(n)]
    ys = [1.0] * n
    ys[12_345] = 3.0  # one sample of a 2 m/s jolt in an hour at 1 m/s
    kept = downsampler(xs, ys, 2000)
    assert 12_345 in kept
    assert 12_345 not in range(0, n, -(-n // 2000))


@DOWNSAMPLERS
def test_lttb_refuses_fewer_than_three_points(downsampler):
    with pytest.raises(ValueError, match="at least 3"):
        downsampler([0.0, 1.0], [0.0, 1.0], 2)


def test_series_are_bounded_and_the_command_keeps_its_steps():
    program = [(1.0, "cw", 1200.0), (2.0, "ccw", 1200.0), (0.5, "cw", 1200.0)]
    rows = drive(program)
    assert len(rows) == 72_000
    collector = SeriesCollector(segments(program), RAIL_M)
    for row in rows:
        collector.take(row)
    series = collector.series(2000)
    for name in ("measured_mps", "battery_v", "track_m"):
        assert len(series[name]["t"]) == len(series[name]["y"]) == 2000
        assert series[name]["t"][0] == 0.0
        assert series[name]["t"][-1] == pytest.approx(rows[-1].t_s)
    # The command is exact: one point per change, and its end.
    assert series["commanded_mps"]["y"] == [1.0, -2.0, 0.5, 0.5]
    assert series["commanded_mps"]["t"] == pytest.approx([0.0, 1200.0, 2400.0, rows[-1].t_s])
    assert min(series["measured_mps"]["y"]) == -2.0
    # The position is unwrapped: 10 m + 1200 m - 2400 m + 600 m (less the last step).
    assert series["track_m"]["y"][0] == 10.0
    assert series["track_m"]["y"][-1] == pytest.approx(10.0 - 600.0 - 0.5 / HZ)
    assert max(series["track_m"]["y"]) == pytest.approx(1210.0, abs=0.1)


def test_without_the_rail_length_the_position_is_charted_as_reported():
    collector = SeriesCollector(segments([(1.0, "cw", 1.0)]))
    for row in drive([(1.0, "cw", 200.0)]):
        collector.take(row)
    ys = collector.series(2000)["track_m"]["y"]
    assert max(ys) <= RAIL_M
    assert min(ys[1:]) < 1.0  # wrapped back past the origin


# -- the same, a column at a time ---------------------------------------------------------------

COLUMN_CASES = [
    ([(1.0, "cw", 600.0), (2.0, "ccw", 600.0), (0.5, "cw", 600.0)], {}, RAIL_M, 50.0),
    ([(2.0, "cw", 120.0)], {"skip": frozenset({3, 4, 9})}, RAIL_M, None),
    ([(1.5, "ccw", 200.0), (0.0, "cw", 10.0)], {"start_m": 0.0}, RAIL_M, 0.0),
    ([(1.0, "cw", 60.0)], {}, None, None),
]


@pytest.mark.parametrize(("program", "drive_options", "rail_m", "pass_at_m"), COLUMN_CASES)
def test_the_column_analysis_is_the_row_by_row_one(program, drive_options, rail_m, pass_at_m):
    """Same additions in the same order: the same floats, not merely close ones."""
    rows = drive(program, **drive_options)
    # Samples outside the program and unknown fixes are counted apart by both.
    rows[5] = rows[5]._replace(segment=None, fix_quality=None)
    rows[6] = rows[6]._replace(segment=len(program))
    options = {"segments": segments(program), "rail_length_m": rail_m, "pass_at_m": pass_at_m}
    expected = analyse(rows, **options)
    assert analyse_columns(SampleColumns.from_rows(rows), **options) == expected


@pytest.mark.parametrize(("program", "drive_options", "rail_m", "pass_at_m"), COLUMN_CASES)
def test_the_column_series_are_the_collectors(program, drive_options, rail_m, pass_at_m):
    rows = drive(program, **drive_options)
    collector = SeriesCollector(segments(program), rail_m)
    for row in rows:
        collector.take(row)
    columns = SampleColumns.from_rows(rows)
    for max_points in (3, 100, 2000):
        series = chart_series(
            columns, segments=segments(program), rail_length_m=rail_m, max_points=max_points
        )
        assert series == collector.series(max_points)


def test_the_column_analysis_of_no_samples_is_empty():
    program = [(1.0, "cw", 10.0)]
    result = analyse_columns(
        SampleColumns.from_rows([]), segments=segments(program), rail_length_m=RAIL_M
    )
    assert result == analyse([], segments=segments(program), rail_length_m=RAIL_M)
    empty = SeriesCollector(segments(program), RAIL_M).series(2000)
    columns = SampleColumns.from_rows([])
    assert (
        chart_series(columns, segments=segments(program), rail_length_m=RAIL_M, max_points=2000)
        == empty
    )
