"""Points placed on a run's path (``portal/runs/placement.py``): exact at sample times, moving
steadily between neighbours, never across a gap, the points outside the run kept and marked,
across the end of the rail the short way round."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from portal.runs.placement import AFTER, BEFORE, GAP, MAX_STEP_S, PLACED, Track, place

RAIL_M = 120.0
TICK_S = 0.02


def _track(
    seqs: list[int],
    times: list[float],
    positions: list[float],
    *,
    rail_length_m: float | None = RAIL_M,
    fix: list[bool] | None = None,
) -> Track:
    n = len(seqs)
    fix = fix if fix is not None else [True] * n
    return Track(
        seq=np.asarray(seqs, dtype=np.int64),
        t_s=np.asarray(times, dtype=np.float64),
        track_m=np.asarray(positions, dtype=np.float64),
        segment=np.asarray([float(k // 10) for k in range(n)]),
        lap=np.zeros(n),
        commanded_velocity_mps=np.full(n, 0.5),
        velocity_mps=np.asarray([0.4 + 0.01 * (k % 7) for k in range(n)]),
        lat_deg=np.asarray([40.6 + k * 1e-6 if ok else np.nan for k, ok in enumerate(fix)]),
        lon_deg=np.asarray([-8.6 - k * 1e-6 if ok else np.nan for k, ok in enumerate(fix)]),
        grid_id=[f"A{1 + k % 4}" for k in range(n)],
        rail_length_m=rail_length_m,
    )


@st.composite
def runs(draw: st.DrawFn) -> Track:
    """A run's samples: ticks of about 20 ms (some repeated, some late), sequence numbers that
    sometimes skip (a gap), a robot going either way round the rail at up to 1.5 m/s."""
    n = draw(st.integers(min_value=1, max_value=60))
    seqs, times, positions = [1], [1_800_000_000.0], [draw(st.floats(0, RAIL_M - 1e-6))]
    for _ in range(n - 1):
        skip = draw(st.sampled_from([1, 1, 1, 1, 2, 5]))
        step_s = draw(st.sampled_from([TICK_S, TICK_S, 0.0, 0.03, MAX_STEP_S + 0.5]))
        speed = draw(st.floats(-1.5, 1.5))
        seqs.append(seqs[-1] + skip)
        times.append(times[-1] + step_s * skip)
        positions.append((positions[-1] + speed * step_s * skip) % RAIL_M)
    return _track(seqs, times, positions)


def _circular_close(a: float, b: float, length_m: float = RAIL_M) -> bool:
    d = abs(a - b) % length_m
    return min(d, length_m - d) < 1e-6


@settings(max_examples=150, deadline=None)
@given(track=runs())
def test_a_point_at_a_samples_time_is_placed_exactly_at_that_sample(track):
    placed = place(track.t_s, track)
    assert np.all(placed.where == PLACED)
    for k in range(len(track.seq)):
        # Samples sharing a time: the point is at the last of them.
        last = int(np.flatnonzero(track.t_s == track.t_s[k])[-1])
        assert _circular_close(placed.track_m[k], track.track_m[last])
        assert placed.grid_id[k] == track.grid_id[last]
        assert placed.velocity_mps[k] == pytest.approx(track.velocity_mps[last])


def _pairs(track: Track) -> list[tuple[int, int, bool]]:
    """Successive samples with time between them: (earlier, later, neighbours)."""
    links = track.neighbours()
    return [
        (k, k + 1, bool(links[k]))
        for k in range(len(track.seq) - 1)
        if track.t_s[k + 1] > track.t_s[k]
    ]


@settings(max_examples=150, deadline=None)
@given(track=runs(), fractions=st.lists(st.floats(0.001, 0.999), min_size=1, max_size=6))
def test_between_neighbours_it_moves_steadily_and_across_a_gap_it_is_unknown(track, fractions):
    unwrapped = track.unwrapped_m()
    for lo, hi, neighbours in _pairs(track):
        times = track.t_s[lo] + np.sort(fractions) * (track.t_s[hi] - track.t_s[lo])
        times = times[(times > track.t_s[lo]) & (times < track.t_s[hi])]
        placed = place(times, track)
        if not neighbours:
            assert np.all(placed.where == GAP)
            assert np.all(np.isnan(placed.track_m))
            assert placed.grid_id == [None] * len(times)
            continue
        assert np.all(placed.where == PLACED)
        low, high = sorted((unwrapped[lo], unwrapped[hi]))
        assert np.all(placed.unwrapped_m >= low - 1e-9)
        assert np.all(placed.unwrapped_m <= high + 1e-9)
        # Monotone in time: the positions go the way the robot went from lo to hi.
        steps = np.diff(placed.unwrapped_m) * np.sign(unwrapped[hi] - unwrapped[lo])
        assert np.all(steps >= -1e-9)
        assert np.all((placed.track_m >= 0) & (placed.track_m < RAIL_M))
        # What held from the earlier sample: its command and segment.
        assert np.all(placed.segment == track.segment[lo])


@settings(max_examples=100, deadline=None)
@given(track=runs(), before_s=st.floats(1e-3, 1e6), after_s=st.floats(1e-3, 1e6))
def test_points_outside_the_run_are_kept_and_marked_and_order_does_not_matter(
    track, before_s, after_s
):
    times = np.concatenate(([track.t_s[0] - before_s], track.t_s, [track.t_s[-1] + after_s]))
    placed = place(times, track)
    assert placed.where[0] == BEFORE
    assert placed.where[-1] == AFTER
    assert math.isnan(placed.track_m[0])
    assert math.isnan(placed.track_m[-1])
    order = np.random.default_rng(len(times)).permutation(len(times))
    shuffled = place(times[order], track)
    assert np.array_equal(shuffled.where, placed.where[order])
    assert np.allclose(shuffled.unwrapped_m, placed.unwrapped_m[order], equal_nan=True)


def test_between_the_end_of_the_rail_and_its_start_it_goes_the_short_way_round():
    track = _track([1, 2], [10.0, 10.02], [119.9, 0.1])
    placed = place(np.asarray([10.01]), track)
    assert placed.where[0] == PLACED
    assert placed.unwrapped_m[0] == pytest.approx(120.0)
    assert _circular_close(placed.track_m[0], 0.0)  # at the origin, never half way round


def test_without_a_fix_on_either_side_there_is_no_gps_position_and_without_a_rail_no_wrap():
    track = _track([1, 2, 3], [0.0, 0.02, 0.04], [1.0, 1.01, 1.02], fix=[True, False, True])
    placed = place(np.asarray([0.01, 0.03]), track)
    assert np.all(np.isnan(placed.lat_deg))
    assert np.all(np.isnan(placed.lon_deg))
    free = _track([1, 2], [0.0, 1.0], [119.0, 121.0], rail_length_m=None)
    assert place(np.asarray([0.5]), free).track_m[0] == pytest.approx(120.0)


def test_a_run_without_samples_places_nothing_and_bad_input_is_refused():
    empty = _track([], [], [])
    placed = place(np.asarray([1.0, 2.0]), empty)
    assert np.all(placed.where == GAP)
    with pytest.raises(ValueError, match="finite"):
        place(np.asarray([1.0, np.nan]), _track([1], [1.0], [0.0]))
    with pytest.raises(ValueError, match="sequence order"):
        _track([2, 1], [0.0, 0.02], [0.0, 0.0])
    with pytest.raises(ValueError, match="rail_length_m"):
        _track([1], [0.0], [0.0], rail_length_m=-1.0)
