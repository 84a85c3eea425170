"""Several finished runs of one robot, each at a chosen time: a researcher's history."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

from django.utils import timezone

from portal.runs.models import Run
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory
from tests.runs.driving import RAIL_M, ingest, segments

PROGRAM = [(0.5, "cw", 2.0), (0.25, "ccw", 1.0)]


def past_run(
    owner: Any,
    mobile: Any,
    *,
    started_at: datetime,
    title: str = "lap",
    program: list[tuple[float, str, float]] = PROGRAM,
    state: str = RunState.COMPLETED,
    experiment: Any = None,
) -> Run:
    """A run of ``program`` on ``mobile`` with its samples, in ``state``, moved to have
    started at ``started_at``. Booked in a free future slot first (bookings lie ahead)."""
    experiment = experiment or ExperimentFactory(
        owner=owner, title=title, segments=segments(program)
    )
    # An hour apart: each run's own slot, whatever times they are moved to afterwards.
    booked = Run.objects.filter(resource=mobile).count()
    start = timezone.now() + timedelta(hours=1 + booked)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=experiment.duration_s + 60),
        experiment=experiment,
    )
    run = reservation.run
    ingest(run, program)
    Run.objects.filter(pk=run.pk).update(
        state=state,
        title=title,
        rail_length_m=RAIL_M,
        start_at=started_at,
        end_at=started_at + (run.end_at - run.start_at),
    )
    run.refresh_from_db()
    return run
