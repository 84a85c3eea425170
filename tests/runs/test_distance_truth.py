"""A run's distance against the simulator's ground truth: the path the robot's physics moved,
not the GPS position's jitter summed.

The simulated robot (``basestation.sim``, on a fake clock, the firmware's ramp, its RTK GPS
with noise) drives a program that starts standing still and stops again in the middle; its
telemetry becomes the samples the agent would store (the position projected on the rail from
each frame's fix) and the portal's analysis reads them. Standing still travels 0 m (the
position's changes summed there come to decimetres); each segment travels what the physics
moved in it, within the body's lag behind the ramp at the segment's speed; the run what the
physics' odometer says, and what the program predicts at the firmware's acceleration.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import pytest

from basestation.protocol import Direction
from basestation.sim.config import SimConfig
from basestation.sim.scenario import Bench
from portal.runs.analysis import SampleRow, analyse
from tests.runs.driving import ramped_travel

# (speed m/s, direction, seconds): standing, cw, standstill (braking, then still), back ccw.
PROGRAM = [(0.0, "cw", 3.0), (0.5, "cw", 6.0), (0.0, "cw", 6.0), (0.8, "ccw", 6.0)]
# The reported speed is the firmware's ramp, within half a duty step (16 mm/s) of the truth,
# held from sample to sample at 50 Hz; the body trails the ramp by the physics' lag (about
# 0.3 s), which moves a little of a segment's path into the next. Over a run it evens out.
STILL_TOLERANCE_M = 0.005
EDGE_TOLERANCE_M = 0.03
RUN_TOLERANCE_M = 0.15


def _drive() -> tuple[list[SampleRow], Bench, list[tuple[float, float]]]:
    """The program on the simulator (and a stop after it); the samples as the agent would
    store them, the bench, and each segment's time span."""
    bench = Bench.create(replace(SimConfig(), seed=11))
    rail = bench.robot.config.rail
    rows: list[SampleRow] = []
    spans = []
    track_m = 0.0
    t0_s = bench.now_s
    for index, (speed_mps, direction, seconds) in enumerate([*PROGRAM, (0.0, "cw", 3.0)]):
        first = len(bench.telemetry)
        start_s = bench.now_s
        bench.drive(seconds, speed_mps, Direction.CW if direction == "cw" else Direction.CCW)
        spans.append((start_s, bench.now_s))
        for t_s, frame in bench.telemetry[first:]:
            if frame.fix_quality:
                track_m = rail.project(frame.lat_e7 / 1e7, frame.lon_e7 / 1e7).track_m
            rows.append(
                SampleRow(
                    seq=len(rows) + 1,
                    t_s=t_s - t0_s,
                    segment=index if index < len(PROGRAM) else None,
                    commanded_velocity_mps=speed_mps,
                    velocity_mps=frame.velocity_mps,
                    direction="cw" if frame.direction == Direction.CW else "ccw",
                    battery_v=frame.battery_v,
                    track_m=track_m,
                    fix_quality=int(frame.fix_quality),
                )
            )
    return rows, bench, spans


def _truth_m(bench: Bench, start_s: float, end_s: float) -> float:
    """What the physics moved between two instants, whatever the direction."""
    trace = [s for s in bench.robot.trace if start_s <= s.time_s <= end_s]
    return sum(abs(b.odometer_m - a.odometer_m) for a, b in itertools.pairwise(trace))


def test_a_standstill_travels_nothing_a_segment_what_the_physics_moved_and_the_run_too():
    rows, bench, spans = _drive()
    rail_m = bench.robot.config.rail.length_m
    lag_s = bench.robot.config.physics.lag_s
    accel_mps2 = bench.robot.firmware_config.accel_mm_s2 / 1000
    segments = [{"velocity_mps": v, "direction": d, "duration_s": s} for v, d, s in PROGRAM]
    result = analyse(rows, segments=segments, rail_length_m=rail_m)
    bench.robot.close()

    # Standing still from the start: the physics moved nothing, and neither did the run;
    # the position's changes summed (the GPS's noise) come to decimetres.
    still = [r for r in rows if r.segment == 0]
    jitter_m = sum(
        min(abs(b.track_m - a.track_m), rail_m - abs(b.track_m - a.track_m))
        for a, b in itertools.pairwise(still)
    )
    assert _truth_m(bench, *spans[0]) == pytest.approx(0.0, abs=STILL_TOLERANCE_M)
    assert jitter_m > 0.1, jitter_m
    assert result.segments[0].distance_m == pytest.approx(0.0, abs=STILL_TOLERANCE_M)

    speeds = [abs(v) for v, _, _ in PROGRAM] + [0.0]
    for index, stats in enumerate(result.segments):
        # Each end of a segment lends or borrows the lag's path at the speed across it.
        edges_mps = max(speeds[max(0, index - 1)], speeds[index], speeds[index + 1])
        tolerance_m = 2 * lag_s * edges_mps + EDGE_TOLERANCE_M
        truth_m = _truth_m(bench, *spans[index])
        assert stats.distance_m == pytest.approx(truth_m, abs=tolerance_m), index
    whole_m = _truth_m(bench, spans[0][0], spans[-1][1])
    assert result.distance_m == pytest.approx(whole_m, abs=RUN_TOLERANCE_M)
    # And the program's own prediction (ramps at the firmware's acceleration) agrees.
    predicted_m, _ = ramped_travel(PROGRAM, accel_mps2)
    assert result.distance_m == pytest.approx(predicted_m, abs=RUN_TOLERANCE_M)
