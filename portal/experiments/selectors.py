from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from datetime import UTC
from typing import Any

from django.db import connection
from django.db.models import QuerySet

from portal.accounts.models import User
from portal.experiments.models import Experiment, Run, Sample


def experiments_visible(*, user: User) -> QuerySet[Experiment]:
    qs = Experiment.objects.select_related("owner")
    return qs if user.is_testbed_admin else qs.filter(owner=user)


def runs_visible(*, user: User) -> QuerySet[Run]:
    qs = Run.objects.select_related("reservation", "reservation__owner", "resource")
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
    "fix_quality",
    "lat_deg",
    "lon_deg",
    "grid_id",
    "lap",
)


CSV_TIME_FORMAT = "%Y-%m-%dT%H:%M:%S.%fZ"


def run_samples_csv(*, run: Run, chunk_rows: int = 5000) -> Iterator[str]:
    """Every sample of a run as CSV text chunks (header first), streamed from the database.

    On PostgreSQL the database writes the CSV itself (``COPY … TO STDOUT``); elsewhere rows
    are formatted here. Both give times as UTC ISO 8601 with microseconds.
    """
    header = ",".join(SAMPLE_EXPORT_FIELDS) + "\r\n"
    yield header
    if connection.vendor == "postgresql":
        columns = ", ".join(
            """to_char(t AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS.US"Z"')""" if f == "t" else f
            for f in SAMPLE_EXPORT_FIELDS
        )
        # COPY takes no bound parameters through Django's debug cursor; the identifiers are
        # this module's constants and the run id is an integer.
        query = (
            f"COPY (SELECT {columns} FROM {Sample._meta.db_table} "  # noqa: S608
            f"WHERE run_id = {int(run.pk)} ORDER BY seq) TO STDOUT WITH (FORMAT csv)"
        )
        with connection.cursor() as cursor, cursor.copy(query) as copy:
            for block in copy:
                yield bytes(block).decode()
        return
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    qs = Sample.objects.filter(run=run).order_by("seq").values_list(*SAMPLE_EXPORT_FIELDS)
    for i, row in enumerate(qs.iterator(chunk_size=chunk_rows), start=1):
        writer.writerow([row[0], row[1].astimezone(UTC).strftime(CSV_TIME_FORMAT), *row[2:]])
        if i % chunk_rows == 0:
            yield buffer.getvalue()
            buffer.seek(0)
            buffer.truncate()
    if buffer.tell():
        yield buffer.getvalue()


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
