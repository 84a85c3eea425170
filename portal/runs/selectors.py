from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from django.core.cache import cache
from django.db import connection
from django.db.models import FloatField, Func, QuerySet

from basestation.contract import SAMPLE_FIELDS
from bookings.models import Reservation
from bookings.selectors import reservations_visible
from portal.accounts.models import User
from portal.runs.analysis import RunAnalysis, SampleRow, SeriesCollector, analyse
from portal.runs.models import Run, Sample
from portal.runs.states import RUN_ACTIVE_STATES, RunState


def runs_visible(*, user: User) -> QuerySet[Run]:
    qs = Run.objects.select_related("reservation", "reservation__owner", "resource")
    return qs if user.is_testbed_admin else qs.filter(reservation__owner=user)


def reservations_with_runs_visible(*, user: User) -> QuerySet[Reservation]:
    """The user's reservations (every one for admins), each with its run if it has one."""
    return reservations_visible(user=user).select_related("run")


def run_ids_by_reservation(reservation_ids: list[int]) -> dict[int, int]:
    """The run of each of these reservations that has one."""
    return dict(
        Run.objects.filter(reservation_id__in=reservation_ids).values_list("reservation_id", "pk")
    )


def run_samples(*, run: Run, after_seq: int = 0, limit: int | None = None) -> QuerySet[Sample]:
    qs = Sample.objects.filter(run=run, seq__gt=after_seq).order_by("seq")
    return qs[:limit] if limit is not None else qs


CSV_TIME_FORMAT = "%Y-%m-%dT%H:%M:%S.%fZ"


def run_samples_csv(*, run: Run, chunk_rows: int = 5000) -> Iterator[str]:
    """Every sample of a run as CSV text chunks (header first), streamed from the database.

    On PostgreSQL the database writes the CSV itself (``COPY … TO STDOUT``); elsewhere rows
    are formatted here. Both give times as UTC ISO 8601 with microseconds.
    """
    header = ",".join(SAMPLE_FIELDS) + "\r\n"
    yield header
    if connection.vendor == "postgresql":
        columns = ", ".join(
            """to_char(t AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS.US"Z"')""" if f == "t" else f
            for f in SAMPLE_FIELDS
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
    qs = Sample.objects.filter(run=run).order_by("seq").values_list(*SAMPLE_FIELDS)
    for i, row in enumerate(qs.iterator(chunk_size=chunk_rows), start=1):
        writer.writerow([row[0], row[1].astimezone(UTC).strftime(CSV_TIME_FORMAT), *row[2:]])
        if i % chunk_rows == 0:
            yield buffer.getvalue()
            buffer.seek(0)
            buffer.truncate()
    if buffer.tell():
        yield buffer.getvalue()


CHART_MAX_POINTS = 2000
# A finished run's samples never change: its report is cached, keyed by what could differ.
REPORT_CACHE_S = 3600
LIVE_REPORT_CACHE_S = 60


@dataclass(frozen=True)
class RunReport:
    """The run page's numbers: analysis, chart series, and the instant ``t_s`` counts from."""

    analysis: RunAnalysis
    series: dict[str, dict[str, list[float]]]
    first_at: datetime | None


class EpochSeconds(Func):
    """A timestamp as float seconds since 1970, computed by the database.

    Reading 72 000 timestamps as datetimes costs more than the whole analysis (the driver
    parses each one in Python); a float costs nothing.
    """

    output_field = FloatField()
    template = "CAST(EXTRACT(EPOCH FROM %(expressions)s) AS double precision)"

    def as_sqlite(self, compiler: Any, connection: Any, **extra: Any) -> Any:
        # SQLite keeps "YYYY-MM-DD HH:MM:SS.ffffff" in UTC; 2440587.5 is 1970-01-01 in Julian days.
        return self.as_sql(
            compiler, connection, template="((julianday(%(expressions)s) - 2440587.5) * 86400.0)"
        )


def _sample_rows(run: Run, first_at: list[datetime]) -> Iterator[SampleRow]:
    rows = (
        Sample.objects.filter(run=run)
        .order_by("seq")
        .annotate(t_epoch_s=EpochSeconds("t"))
        .values_list(*(("t_epoch_s" if f == "t_s" else f) for f in SampleRow._fields))
    )
    first_s = 0.0
    for seq, epoch_s, segment, commanded, measured, direction, battery, track, fix in rows.iterator(
        chunk_size=5000
    ):
        if not first_at:
            first_s = epoch_s
            first_at.append(datetime.fromtimestamp(epoch_s, UTC))
        t_s = epoch_s - first_s
        yield SampleRow(seq, t_s, segment, commanded, measured, direction, battery, track, fix)


def run_report(
    *, run: Run, pass_at_m: float | None = None, max_points: int = CHART_MAX_POINTS
) -> RunReport:
    """Everything the run page shows, from one ordered read of the samples.

    Raises ``ValueError`` (with a message for the user) for a position off the rail.
    """
    final = run.state not in RUN_ACTIVE_STATES and run.state != RunState.SCHEDULED
    # created_at tells this run from one with the same id in another database (a restore).
    identity: tuple[object, ...] = (
        run.pk,
        run.created_at.timestamp(),
        run.state,
        run.last_seq,
        run.rail_length_m,
    )
    if not final:
        # While samples arrive (a gap may be filled below last_seq), their count says whether
        # anything changed: every viewer's poll then costs one count, not a recomputation.
        identity += (Sample.objects.filter(run=run).count(),)
    key = f"run-report:{identity}:{pass_at_m}:{max_points}".replace(" ", "")
    cached = cache.get(key)
    if isinstance(cached, RunReport):
        return cached
    first_at: list[datetime] = []
    collector = SeriesCollector(run.segments, run.rail_length_m)
    analysis = analyse(
        (collector.take(row) for row in _sample_rows(run, first_at)),
        segments=run.segments,
        rail_length_m=run.rail_length_m,
        pass_at_m=pass_at_m,
    )
    report = RunReport(analysis, collector.series(max_points), first_at[0] if first_at else None)
    cache.set(key, report, REPORT_CACHE_S if final else LIVE_REPORT_CACHE_S)
    return report


def _at(first_at: datetime | None, t_s: float) -> str | None:
    if first_at is None:
        return None
    return (first_at + timedelta(seconds=t_s)).astimezone(UTC).isoformat()


def run_report_json(report: RunReport) -> dict[str, Any]:
    """The analysis as JSON for the REST API and the run page: seconds since the first
    sample (``*_s``) and UTC instants (``*_at``) side by side."""
    a, first_at = report.analysis, report.first_at
    return {
        "samples": a.samples,
        "missing": a.missing,
        "gaps": [{"first_seq": g.first_seq, "last_seq": g.last_seq} for g in a.gaps],
        "outside_program": a.outside_program,
        "first_at": _at(first_at, 0.0),
        "duration_s": round(a.duration_s, 3),
        "rail_length_m": a.rail_length_m,
        "distance_m": None if a.distance_m is None else round(a.distance_m, 3),
        "mean_speed_mps": None if a.mean_speed_mps is None else round(a.mean_speed_mps, 4),
        "net_laps": a.net_laps,
        "segments": [
            {
                "index": s.index,
                "commanded_mps": s.commanded_mps,
                "samples": s.samples,
                "start_s": round(s.start_s, 3),
                "duration_s": round(s.duration_s, 3),
                "distance_m": round(s.distance_m, 3),
                "mean_mps": round(s.mean_mps, 4),
                "min_mps": round(s.min_mps, 4),
                "max_mps": round(s.max_mps, 4),
                "std_mps": round(s.std_mps, 4),
                "mean_abs_error_mps": round(s.mean_abs_error_mps, 4),
                "battery_start_v": s.battery_start_v,
                "battery_end_v": s.battery_end_v,
                "battery_min_v": s.battery_min_v,
                "rtk_fixed_share": round(s.rtk_fixed_share, 4),
            }
            for s in a.segments
        ],
        "laps": [
            {
                "index": lap.index,
                "start_s": round(lap.start_s, 3),
                "end_s": round(lap.end_s, 3),
                "end_at": _at(first_at, lap.end_s),
                "duration_s": round(lap.duration_s, 3),
                "mean_speed_mps": round(lap.mean_speed_mps, 4),
            }
            for lap in a.laps
        ],
        "pass_at_m": a.pass_at_m,
        "passes": [
            {
                "index": p.index,
                "t_s": round(p.t_s, 3),
                "at": _at(first_at, p.t_s),
                "direction": p.direction,
                "velocity_mps": round(p.velocity_mps, 4),
            }
            for p in a.passes
        ],
    }


def run_samples_json(*, run: Run, chunk_rows: int = 2000) -> Iterator[str]:
    """Every sample of a run as one JSON document, streamed in chunks (never built whole)."""
    head = {
        "run": run.pk,
        "title": run.title,
        "resource": run.resource.name,
        "state": run.state,
        "segments": run.segments,
        "rail_length_m": run.rail_length_m,
    }
    yield json.dumps(head)[:-1] + ', "samples": ['
    qs = Sample.objects.filter(run=run).order_by("seq").values_list(*SAMPLE_FIELDS)
    batch: list[str] = []
    first = True
    for row in qs.iterator(chunk_size=chunk_rows):
        record = dict(zip(SAMPLE_FIELDS, row, strict=True))
        record["t"] = record["t"].astimezone(UTC).strftime(CSV_TIME_FORMAT)
        batch.append(json.dumps(record))
        if len(batch) == chunk_rows:
            yield ("" if first else ",") + ",".join(batch)
            first, batch = False, []
    if batch:
        yield ("" if first else ",") + ",".join(batch)
    yield "]}"
