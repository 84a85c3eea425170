"""A robot that drives its program exactly, sampled at the agent's 20 Hz: test data whose
laps, passes and statistics can be worked out by hand."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from django.utils import timezone

from portal.runs.analysis import SampleRow
from portal.runs.models import Run, Sample
from portal.runs.services.collection import samples_ingest
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, MobileResourceFactory

HZ = 20
RAIL_M = 100.0


def drive(
    program: list[tuple[float, str, float]],
    *,
    start_m: float = 10.0,
    battery_v: float = 60.0,
    skip: frozenset[int] = frozenset(),
) -> list[SampleRow]:
    """Ideal samples of a robot driving ``program`` [(speed m/s, cw|ccw, seconds)] at 20 Hz:
    it starts at ``start_m`` and moves exactly as commanded. ``skip`` drops those seqs."""
    rows = []
    position_m = start_m
    seq = 0
    t_s = 0.0
    for index, (speed_mps, direction, duration_s) in enumerate(program):
        for _ in range(round(duration_s * HZ)):
            seq += 1
            if seq not in skip:
                rows.append(
                    SampleRow(
                        seq=seq,
                        t_s=t_s,
                        segment=index,
                        commanded_velocity_mps=speed_mps,
                        velocity_mps=speed_mps,
                        direction=direction,
                        battery_v=battery_v - t_s / 100.0,
                        track_m=position_m % RAIL_M,
                        fix_quality=4 if seq % 4 else 5,
                    )
                )
            step_m = speed_mps / HZ
            position_m += step_m if direction == "cw" else -step_m
            t_s += 1.0 / HZ
    return rows


def segments(program: list[tuple[float, str, float]]) -> list[dict[str, object]]:
    return [{"velocity_mps": v, "direction": d, "duration_s": s} for v, d, s in program]


def ingest(run: Any, program: list[tuple[float, str, float]]) -> None:
    """Store the samples of ``program`` for ``run`` as collection would."""
    t0_s = run.start_at.timestamp()
    samples_ingest(
        run=run,
        samples=[
            {
                **{k: v for k, v in row._asdict().items() if k != "t_s"},
                "t": t0_s + row.t_s,
                "lat_deg": None,
                "lon_deg": None,
                "grid_id": None,
                "lap": None,
            }
            for row in drive(program)
        ],
    )


def completed_run(
    owner: Any,
    mobile: Any,
    program: list[tuple[float, str, float]],
    *,
    rail_length_m: float | None = RAIL_M,
    hours_ahead: float = 1.0,
) -> Any:
    """A booked run of ``program`` on ``mobile``, its samples stored, marked completed."""
    experiment = ExperimentFactory(owner=owner, segments=segments(program))
    start = timezone.now() + timedelta(hours=hours_ahead)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=experiment.duration_s + 60),
        experiment=experiment,
    )
    run = reservation.run
    ingest(run, program)
    Run.objects.filter(pk=run.pk).update(state=RunState.COMPLETED, rail_length_m=rail_length_m)
    run.refresh_from_db()
    return run


def ramped_travel(
    segments: list[tuple[float, str, float]], accel_mps2: float
) -> tuple[float, float]:
    """Distance and signed displacement (cw +) of the robot slewing its velocity at
    ``accel_mps2`` towards each segment's, then to a stop: integrated in small steps, apart
    from the page's exact arithmetic."""
    step_s = 1e-4
    v = distance = displacement = 0.0
    targets = [((1 if d == "cw" else -1) * mps, s) for mps, d, s in segments]

    def drive(target: float, for_s: float | None) -> None:
        nonlocal v, distance, displacement
        elapsed = 0.0
        while (elapsed < for_s - step_s / 2) if for_s is not None else abs(v) > 1e-12:
            dv = max(-accel_mps2 * step_s, min(accel_mps2 * step_s, target - v))
            mean = v + dv / 2
            v += dv
            distance += abs(mean) * step_s
            displacement += mean * step_s
            elapsed += step_s

    for target, duration_s in targets:
        drive(target, duration_s)
    drive(0.0, None)
    return distance, displacement


# A run round a rail of 120 m, a grid cell every 10 m (run_round_the_rail).
ROUND_RAIL_M = 120.0
CELL_M = 10.0


def cell_of(track_m: float) -> str:
    return f"A{int(track_m // CELL_M) + 1}"


def run_round_the_rail(
    owner: Any, *, speed_mps: float = 1.0, seconds: float = 30.0, hours_ahead: float = 1.0
) -> Any:
    """A completed run whose samples go round the rail at ``speed_mps`` from 0 m, every 0.1 s,
    each with its grid cell (``cell_of``)."""
    run = completed_run(owner, MobileResourceFactory(), [(0.5, "cw", 1.0)], hours_ahead=hours_ahead)
    Sample.objects.filter(run=run).delete()
    t0_s = run.start_at.timestamp()
    samples = []
    for seq in range(1, int(seconds * 10) + 1):
        t_s = (seq - 1) / 10
        track_m = (speed_mps * t_s) % ROUND_RAIL_M
        samples.append(
            {
                "seq": seq,
                "t": t0_s + t_s,
                "segment": 0,
                "commanded_velocity_mps": speed_mps,
                "velocity_mps": speed_mps,
                "direction": "cw",
                "battery_v": 60.0,
                "track_m": track_m,
                "fix_quality": None,
                "lat_deg": None,
                "lon_deg": None,
                "grid_id": cell_of(track_m),
                "lap": int(speed_mps * t_s // ROUND_RAIL_M),
            }
        )
    samples_ingest(run=run, samples=samples)
    run.rail_length_m = ROUND_RAIL_M
    run.save(update_fields=["rail_length_m"])
    return run
