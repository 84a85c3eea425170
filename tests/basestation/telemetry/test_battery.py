"""Battery median filter (thesis §3.4, figure 3.20)."""

from __future__ import annotations

import math
import statistics

import pytest

from basestation.telemetry import BatteryFilter, MedianFilter

# A 61 V battery read with the kind of errors the thesis saw: single readings far too
# high or far too low, fewer than half of any 9-sample window.
TRUE_V = 61.0
SPIKY_V = [61.0, 61.1, 12.0, 60.9, 61.0, 99.0, 61.1, 0.0, 60.9, 61.0, 61.0, 70.5, 60.9, 61.1]


def test_the_median_rejects_spikes_that_a_mean_does_not() -> None:
    battery = BatteryFilter(window=9)
    filtered_v = [battery.add(v) for v in SPIKY_V]
    means_v = [statistics.fmean(SPIKY_V[max(0, k - 8) : k + 1]) for k in range(len(SPIKY_V))]

    # Once the window is full, every median is a real reading of the battery ...
    assert all(abs(v - TRUE_V) <= 0.1 for v in filtered_v[8:])
    # ... while the mean of the same windows is volts away.
    assert max(abs(v - TRUE_V) for v in means_v[8:]) > 3.0
    assert battery.battery_v == pytest.approx(TRUE_V, abs=0.1)


def test_it_starts_empty_and_follows_a_real_change_within_half_a_window() -> None:
    battery = BatteryFilter()
    assert battery.window == 9
    assert battery.battery_v is None
    assert len(battery) == 0
    for _ in range(9):
        battery.add(60.0)
    readings = [battery.add(58.0) for _ in range(5)]
    assert readings[3] == 60.0  # four of nine new readings: still the old voltage
    assert readings[4] == 58.0  # five of nine: the new one
    battery.clear()
    assert battery.value is None


@pytest.mark.parametrize("window", [0, -1, 2.5, True])
def test_it_refuses_a_window_that_is_not_a_positive_integer(window: object) -> None:
    with pytest.raises(ValueError, match="window"):
        MedianFilter(window)  # type: ignore[arg-type]


@pytest.mark.parametrize("reading", [math.nan, math.inf, -math.inf])
def test_it_refuses_non_finite_readings_without_storing_them(reading: float) -> None:
    battery = BatteryFilter(window=3)
    battery.add(60.0)
    with pytest.raises(ValueError, match="finite"):
        battery.add(reading)
    assert len(battery) == 1
    assert battery.value == 60.0
