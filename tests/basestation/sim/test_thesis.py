"""The thesis's stop and velocity tests (chapter 4), redone on the simulator.

These are the numbers of docs/simulator.md (``python -m basestation.sim.report`` prints the
full tables); here fewer speeds and a shorter hold keep the suite fast.
"""

from __future__ import annotations

import pytest

from basestation.sim.scenario import DUTY_STEP_MPS, stop_test, velocity_test


@pytest.mark.parametrize("kind", ["link_cut", "commanded", "e_stop"])
def test_stop_distance_grows_with_velocity(kind: str) -> None:
    results = [stop_test(kind, v) for v in (0.5, 1.0, 2.0)]  # type: ignore[arg-type]
    distances = [r.distance_m for r in results]
    assert distances == sorted(distances)
    assert distances[0] < distances[1] < distances[2]
    for result in results:
        assert 0.0 < result.distance_m <= result.bound_m
        if kind == "link_cut":  # it kept going for the dead-man's 500 ms first
            assert result.distance_m > 0.5 * result.speed_at_stop_mps


@pytest.mark.parametrize("fix", ["rtk_fixed", "rtk_float"])
@pytest.mark.parametrize("velocity_mps", [0.5, 2.0])
def test_gps_derived_velocity_agrees_with_the_reported_within_noise(
    fix: str, velocity_mps: float
) -> None:
    result = velocity_test(fix, velocity_mps, hold_s=10.0)
    assert result.reported_mps == pytest.approx(velocity_mps, abs=1e-3)
    assert abs(result.true_mps - velocity_mps) <= DUTY_STEP_MPS / 2
    # The GPS measures the body, within its noise (3 sigma of the least-squares speed)...
    assert abs(result.gps_minus_true_mps) <= 3 * result.gps_sigma_mps
    # ...and the robot reports its ramp's speed, which the 8-bit duty can only approximate
    # to half a duty step (16 mm/s).
    assert abs(result.gps_minus_reported_mps) <= 3 * result.gps_sigma_mps + DUTY_STEP_MPS / 2
    assert result.fixes >= 95
