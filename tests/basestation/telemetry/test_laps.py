"""Unwrapping track_m across the seam, laps, and passes at a chosen position."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from basestation.telemetry import LapCounter, unwrap_track, wrap_delta_m

LENGTH_M = 120.0
PERIOD_S = 0.05


def drive(
    counter: LapCounter,
    velocity_signed_mps: float,
    seconds: float,
    t0_s: float = 0.0,
    start_m: float = 0.0,
) -> float:
    """Feed ``seconds`` of constant motion at 20 Hz; return the time after the last sample."""
    steps = round(seconds / PERIOD_S)
    for k in range(steps + 1):
        t_s = t0_s + k * PERIOD_S
        counter.update(
            (start_m + velocity_signed_mps * k * PERIOD_S) % LENGTH_M, t_s, abs(velocity_signed_mps)
        )
    return t0_s + steps * PERIOD_S


def test_clockwise_laps_count_across_the_seam() -> None:
    counter = LapCounter(LENGTH_M)
    drive(counter, 2.0, 150.0, start_m=100.0)  # 300 m: two and a half laps
    assert counter.net_m == pytest.approx(300.0)
    assert counter.laps == 2
    assert counter.laps_travelled == 2
    assert counter.unwrapped_m == pytest.approx(400.0)


def test_counter_clockwise_laps_are_negative() -> None:
    counter = LapCounter(LENGTH_M)
    drive(counter, -1.5, 170.0, start_m=10.0)  # 255 m the other way
    assert counter.net_m == pytest.approx(-255.0)
    assert counter.laps == -2
    assert counter.laps_travelled == 2


def test_there_and_back_makes_no_net_lap_but_travels_some() -> None:
    counter = LapCounter(LENGTH_M)
    end_s = drive(counter, 2.0, 90.0, start_m=5.0)  # 1.5 laps cw
    drive(counter, -2.0, 90.0, t0_s=end_s, start_m=(5.0 + 180.0) % LENGTH_M)
    assert counter.net_m == pytest.approx(0.0, abs=1e-6)
    assert counter.laps == 0
    assert counter.laps_travelled == 3


def test_passes_at_a_position_have_their_time_direction_and_velocity() -> None:
    counter = LapCounter(LENGTH_M, pass_at_m=30.0)
    end_s = drive(counter, 2.0, 130.0, start_m=0.0)  # 260 m cw: passes at 30 m and 150 m
    assert [p.direction for p in counter.passes] == ["cw", "cw"]
    assert [p.index for p in counter.passes] == [1, 2]
    assert [p.t_s for p in counter.passes] == pytest.approx([15.0, 75.0])
    assert all(p.velocity_mps == pytest.approx(2.0) for p in counter.passes)
    # Back the other way from 260 m (20 m on the rail): the next crossing is the one at
    # 150 m again, 110 m behind, at 1 m/s.
    new = []
    for k in range(1, 200 * 20):
        found = counter.update((20.0 - k * PERIOD_S) % LENGTH_M, end_s + k * PERIOD_S, 1.0)
        new.extend(found)
        if found:
            break
    assert len(new) == 1
    assert new[0].direction == "ccw"
    assert new[0].t_s == pytest.approx(end_s + 110.0)
    assert new[0].velocity_mps == pytest.approx(1.0)
    assert new[0].index == 3


def test_a_pass_velocity_falls_back_to_the_position_change() -> None:
    counter = LapCounter(LENGTH_M, pass_at_m=0.0)
    counter.update(119.0, 10.0)
    (found,) = counter.update(1.0, 10.5)  # 2 m across the seam in 0.5 s
    assert found.t_s == pytest.approx(10.25)
    assert found.velocity_mps == pytest.approx(4.0)
    assert found.direction == "cw"


def test_standing_on_the_position_and_turning_back_is_two_crossings() -> None:
    counter = LapCounter(LENGTH_M, pass_at_m=50.0)
    for k, track_m in enumerate([49.0, 49.5, 50.0, 49.5]):
        counter.update(track_m, k * 1.0, 0.5)
    assert [(p.direction, p.t_s) for p in counter.passes] == [("cw", 2.0), ("ccw", 2.0)]


def test_it_refuses_nonsense() -> None:
    with pytest.raises(ValueError, match="length_m"):
        LapCounter(0.0)
    with pytest.raises(ValueError, match="pass_at_m"):
        LapCounter(LENGTH_M, pass_at_m=math.nan)
    counter = LapCounter(LENGTH_M)
    with pytest.raises(ValueError, match="finite"):
        counter.update(math.inf, 0.0)
    assert counter.unwrapped_m is None


@given(
    start_m=st.floats(min_value=0.0, max_value=LENGTH_M, exclude_max=True),
    steps_m=st.lists(st.floats(min_value=-LENGTH_M / 2.01, max_value=LENGTH_M / 2.01), max_size=60),
)
def test_unwrapping_is_continuous(start_m: float, steps_m: list[float]) -> None:
    true_m = list(itertools.accumulate(steps_m, initial=start_m))
    wrapped_m = [value % LENGTH_M for value in true_m]
    unwrapped_m = unwrap_track(wrapped_m, LENGTH_M)
    for a_m, b_m, step_m in zip(unwrapped_m, unwrapped_m[1:], steps_m, strict=False):
        assert b_m - a_m == pytest.approx(step_m, abs=1e-6)
    for value_m, wrapped in zip(unwrapped_m, wrapped_m, strict=True):
        assert math.isclose(value_m % LENGTH_M, wrapped, abs_tol=1e-6) or math.isclose(
            abs(value_m % LENGTH_M - wrapped), LENGTH_M, abs_tol=1e-6
        )


@given(
    start_m=st.floats(min_value=0.0, max_value=LENGTH_M, exclude_max=True),
    steps_m=st.lists(st.floats(min_value=-LENGTH_M / 2.01, max_value=LENGTH_M / 2.01), max_size=60),
    pass_at_m=st.floats(min_value=0.0, max_value=LENGTH_M, exclude_max=True),
)
def test_the_counter_agrees_with_the_unwrapped_track(
    start_m: float, steps_m: list[float], pass_at_m: float
) -> None:
    true_m = list(itertools.accumulate(steps_m, initial=start_m))
    counter = LapCounter(LENGTH_M, pass_at_m=pass_at_m)
    for k, value_m in enumerate(true_m):
        counter.update(value_m % LENGTH_M, float(k))
    assert counter.net_m == pytest.approx(true_m[-1] - true_m[0], abs=1e-6)
    assert counter.distance_m == pytest.approx(sum(abs(s) for s in steps_m), abs=1e-6)
    # Passes alternate sensibly: the net count of crossings matches the net cells moved.
    cw = sum(p.direction == "cw" for p in counter.passes)
    ccw = len(counter.passes) - cw
    assert counter.unwrapped_m is not None
    assert counter.start_m is not None
    cells = math.floor((counter.unwrapped_m - pass_at_m) / LENGTH_M) - math.floor(
        (counter.start_m - pass_at_m) / LENGTH_M
    )
    assert cw - ccw == cells
    assert all(t1.t_s <= t2.t_s for t1, t2 in itertools.pairwise(counter.passes))


def test_wrap_delta_takes_the_shorter_way() -> None:
    assert wrap_delta_m(119.0, LENGTH_M) == pytest.approx(-1.0)
    assert wrap_delta_m(-119.0, LENGTH_M) == pytest.approx(1.0)
    assert wrap_delta_m(3.0, LENGTH_M) == pytest.approx(3.0)
