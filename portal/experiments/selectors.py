from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from django.db.models import QuerySet

from portal.accounts.models import User
from portal.experiments.models import Experiment, Run, Sample


def experiments_visible(*, user: User) -> QuerySet[Experiment]:
    qs = Experiment.objects.select_related("owner")
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def runs_visible(*, user: User) -> QuerySet[Run]:
    qs = Run.objects.select_related("reservation", "reservation__owner", "reservation__resource")
    return qs if user.is_testbed_admin else qs.filter(reservation__owner=user)


def run_samples(*, run: Run, after_seq: int = 0, limit: int | None = None) -> QuerySet[Sample]:
    qs = Sample.objects.filter(run=run, seq__gt=after_seq).order_by("seq")
    return qs[:limit] if limit is not None else qs


SAMPLE_EXPORT_FIELDS = (
    "seq",
    "t",
    "segment",
    "commanded_velocity_mps",
    "velocity_mps",
    "direction",
    "battery_v",
    "track_m",
)


def run_sample_rows(*, run: Run, chunk_size: int = 5000) -> Iterator[tuple[Any, ...]]:
    """Every sample of a run as a tuple of ``SAMPLE_EXPORT_FIELDS``, streamed from the database."""
    qs = Sample.objects.filter(run=run).order_by("seq").values_list(*SAMPLE_EXPORT_FIELDS)
    yield from qs.iterator(chunk_size=chunk_size)


def run_velocity_series(*, run: Run, max_points: int = 2000) -> dict[str, list[Any]]:
    """Commanded and measured velocity for the run page's chart, at most ``max_points``.

    Evenly strided for now; charts never receive the raw sample count of a long run.
    """
    count = Sample.objects.filter(run=run).count()
    stride = max(1, -(-count // max_points))
    rows = (
        Sample.objects.filter(run=run)
        .order_by("seq")
        .values_list("t", "segment", "commanded_velocity_mps", "velocity_mps", "direction")
    )
    series: dict[str, list[Any]] = {"t": [], "commanded_mps": [], "measured_mps": []}
    t0 = None
    # Signed velocities: clockwise positive, so a reversal shows as crossing zero.
    commanded_sign = [-1.0 if s["direction"] == "ccw" else 1.0 for s in run.segments]
    for i, (t, segment, commanded, measured, direction) in enumerate(
        rows.iterator(chunk_size=5000)
    ):
        if i % stride:
            continue
        t0 = t0 or t
        sign = commanded_sign[segment] if segment is not None else 1.0
        series["t"].append(round((t - t0).total_seconds(), 3))
        series["commanded_mps"].append(sign * commanded)
        series["measured_mps"].append(round((-1.0 if direction == "ccw" else 1.0) * measured, 4))
    return series
