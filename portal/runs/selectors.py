from __future__ import annotations

import io
import json
from collections.abc import Iterator
from dataclasses import dataclass, replace
from datetime import UTC, datetime, timedelta
from typing import Any

from django.core.cache import cache
from django.db.models import QuerySet

from basestation.contract import SAMPLE_FIELDS, CsvWriter
from bookings.models import PeriodQuerySet, Reservation, ReservationItem, Resource
from bookings.rules import velocity_limit
from bookings.selectors import mobiles_bookable, reservations_visible
from core import sql
from core.accounts.models import User
from core.cache import database_namespace
from portal.runs import queries
from portal.runs.analysis import (
    RailTrack,
    RunAnalysis,
    SampleColumns,
    SampleRow,
    analyse_columns,
    chart_series,
    passes_at,
    rail_track,
)
from portal.runs.models import (
    DryRun,
    Run,
    Sample,
    SelfCheck,
    SelfCheckBaseline,
    SelfCheckSchedule,
)
from portal.runs.states import RUN_ACTIVE_STATES, RunState


def robots_for_programs() -> list[dict[str, Any]]:
    """The robots that may be booked, with the limits booking holds a program to (``None``:
    none) and their rails' lengths as last measured (``None``: never)."""
    return [robot_for_programs(robot) for robot in mobiles_bookable()]


def robot_for_programs(robot: Resource) -> dict[str, Any]:
    """One robot's entry of :func:`robots_for_programs`."""
    limit = velocity_limit(robot)
    accel = robot.max_accel_mps2
    if robot.agent_max_accel_mps2 is not None:
        accel = (
            robot.agent_max_accel_mps2 if accel is None else min(accel, robot.agent_max_accel_mps2)
        )
    # The rail is measured by the robot on each run; its latest run says it best.
    rail_m = (
        Run.objects.filter(resource=robot, rail_length_m__isnull=False)
        .order_by("-start_at")
        .values_list("rail_length_m", flat=True)
        .first()
    )
    return {
        "name": robot.name,
        "max_velocity_mps": limit.mps if limit is not None else None,
        "max_accel_mps2": accel,
        "rail_length_m": rail_m,
    }


def runs_visible(*, user: User) -> QuerySet[Run]:
    qs = Run.objects.select_related("reservation", "reservation__owner", "resource")
    return qs if user.is_testbed_admin else qs.filter(reservation__owner=user)


def reservations_with_runs_visible(*, user: User) -> PeriodQuerySet[Reservation]:
    """The user's reservations (every one for admins), each with its run if it has one."""
    return reservations_visible(user=user).select_related("run")


# What a reservation's row in a list shows, besides its resources (``reservation_resources``):
# read as plain values, a list of a hundred builds no model instance.
LISTED_COLUMNS = (
    "id",
    "owner__username",
    "title",
    "start_at",
    "end_at",
    "state",
    "run__id",
    "run__state",
    "override_reason",
    "decision_reason",
    "cancel_reason",
    "conflict",
    "created_at",
)


def reservations_listed(*, user: User) -> PeriodQuerySet[Reservation]:
    """The user's reservations (every one for admins), to be filtered, then read as
    ``.values(*LISTED_COLUMNS)`` with ``reservation_resources`` for the page read. Building
    model instances, their owners, runs and a prefetch per reservation was most of a list's
    time (14 ms for a hundred)."""
    return reservations_visible(user=user).select_related(None).prefetch_related(None)


def reservation_resources(reservation_ids: list[int]) -> dict[int, list[tuple[str, str]]]:
    """Each of these reservations' resources as (name, kind), in the order they were booked."""
    resources: dict[int, list[tuple[str, str]]] = {pk: [] for pk in reservation_ids}
    items = (
        ReservationItem.objects.filter(reservation_id__in=reservation_ids)
        .order_by("pk")
        .values_list("reservation_id", "resource__name", "resource__kind")
    )
    for reservation_id, name, kind in items:
        resources[reservation_id].append((name, kind))
    return resources


def run_ids_by_reservation(reservation_ids: list[int]) -> dict[int, int]:
    """The run of each of these reservations that has one."""
    return dict(
        Run.objects.filter(reservation_id__in=reservation_ids).values_list("reservation_id", "pk")
    )


def run_samples(*, run: Run, after_seq: int = 0, limit: int | None = None) -> QuerySet[Sample]:
    qs = Sample.objects.filter(run=run, seq__gt=after_seq).order_by("seq")
    return qs[:limit] if limit is not None else qs


CSV_TIME_FORMAT = "%Y-%m-%dT%H:%M:%S.%fZ"


def run_samples_csv(*, run: Run, chunk_rows: int = 5000) -> Iterator[bytes]:
    """Every sample of a run as CSV (UTF-8, header first) in chunks, streamed from the
    database, columns in the contract's order.

    On PostgreSQL the database writes the CSV itself (``COPY … TO STDOUT``); elsewhere rows
    are formatted here. Both give times as UTC ISO 8601 with microseconds.
    """
    yield (",".join(SAMPLE_FIELDS) + "\r\n").encode()
    if sql.is_postgresql():
        yield from queries.samples_csv_copy(run.pk)
        return
    buffer = io.StringIO()
    writer = CsvWriter(buffer)
    qs = Sample.objects.filter(run=run).order_by("seq").values(*SAMPLE_FIELDS)
    for i, row in enumerate(qs.iterator(chunk_size=chunk_rows), start=1):
        row["t"] = row["t"].astimezone(UTC).strftime(CSV_TIME_FORMAT)
        writer.writerow(row[f] for f in SAMPLE_FIELDS)
        if i % chunk_rows == 0:
            yield buffer.getvalue().encode()
            buffer.seek(0)
            buffer.truncate()
    if buffer.tell():
        yield buffer.getvalue().encode()


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
    # Passes at any position are found from it (report_with_passes), not by a new report.
    track: RailTrack | None = None


def _sample_columns(run: Run) -> tuple[SampleColumns, datetime | None]:
    """The run's samples a column at a time, times as seconds since the first sample; and
    when that first sample was."""
    columns = queries.sample_columns(run)
    if not len(columns):
        return columns, None
    first_s = float(columns.t_s[0])
    return replace(columns, t_s=columns.t_s - first_s), datetime.fromtimestamp(first_s, UTC)


def run_report(
    *,
    run: Run,
    pass_at_m: float | None = None,
    max_points: int = CHART_MAX_POINTS,
    cached: bool = True,
) -> RunReport:
    """Everything the run page shows, from one ordered read of the samples.

    Served from the cache while nothing it depends on changed; ``cached=False`` computes it
    afresh (and stores nothing). The passes at ``pass_at_m`` are not part of what is cached:
    they are found from the cached report's track, so a viewer trying positions costs no
    new report and adds nothing to the cache. Raises ``ValueError`` (with a message for the
    user) for a position off the rail.
    """
    if not cached:
        return _run_report_computed(run, pass_at_m, max_points)
    report = _run_report_cached(run, max_points)
    return report if pass_at_m is None else report_with_passes(report, pass_at_m)


def report_with_passes(report: RunReport, pass_at_m: float) -> RunReport:
    """``report`` with its passes at ``pass_at_m`` (``ValueError`` for a position off the
    rail, or a run without the rail length)."""
    passes = passes_at(report.track, pass_at_m, rail_length_m=report.analysis.rail_length_m)
    analysis = replace(report.analysis, pass_at_m=pass_at_m, passes=passes)
    return replace(report, analysis=analysis)


def _report_identity(run: Run) -> tuple[str, int]:
    """What a run's report is computed from, as a cache key's part, and how long an answer
    computed from it may be kept (s)."""
    final = run.state not in RUN_ACTIVE_STATES and run.state != RunState.SCHEDULED
    # created_at tells this run from one with the same id in the same database (a restore).
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
    part = f"{database_namespace()}:{identity}".replace(" ", "")
    return part, REPORT_CACHE_S if final else LIVE_REPORT_CACHE_S


def _run_report_cached(
    run: Run, max_points: int, identity: tuple[str, int] | None = None
) -> RunReport:
    identity_part, keep_s = identity or _report_identity(run)
    key = f"run-report:v2:{identity_part}:{max_points}"
    hit = cache.get(key)
    if isinstance(hit, RunReport):
        return hit
    report = _run_report_computed(run, None, max_points)
    cache.set(key, report, keep_s)
    return report


def run_analysis_json(*, run: Run, pass_at_m: float | None = None) -> dict[str, Any]:
    """The run's analysis as the REST API gives it (``run_report_json``).

    Without ``pass_at_m`` the answer itself is kept beside the report, under the same
    identity: a script polling a run's analysis reads a few hundred bytes instead of the
    report with its chart series and track, and builds nothing. Raises ``ValueError`` (with a
    message for the user) for a position off the rail.
    """
    if pass_at_m is not None:
        return run_report_json(run_report(run=run, pass_at_m=pass_at_m))
    identity = _report_identity(run)
    key = f"run-analysis:v1:{identity[0]}"
    hit = cache.get(key)
    if isinstance(hit, dict):
        return hit
    # The report under the identity just read (a live run's is a count of its samples).
    answer = run_report_json(_run_report_cached(run, CHART_MAX_POINTS, identity))
    cache.set(key, answer, identity[1])
    return answer


def _run_report_computed(run: Run, pass_at_m: float | None, max_points: int) -> RunReport:
    columns, first_at = _sample_columns(run)
    analysis = analyse_columns(
        columns, segments=run.segments, rail_length_m=run.rail_length_m, pass_at_m=pass_at_m
    )
    series = chart_series(
        columns, segments=run.segments, rail_length_m=run.rail_length_m, max_points=max_points
    )
    return RunReport(analysis, series, first_at, rail_track(columns, run.rail_length_m))


def dry_run_report(
    *, dry_run: DryRun, pass_at_m: float | None = None, max_points: int = CHART_MAX_POINTS
) -> RunReport:
    """What a dry run's page shows, as a run's (``run_report``): its samples are its own,
    timed from its start. Raises ``ValueError`` for a position off the rail."""
    samples = dry_run.samples or []
    t0 = float(samples[0]["t"]) if samples else 0.0
    columns = SampleColumns.from_rows(
        SampleRow(
            seq=int(s["seq"]),
            t_s=float(s["t"]) - t0,
            segment=s["segment"],
            commanded_velocity_mps=float(s["commanded_velocity_mps"]),
            velocity_mps=float(s["velocity_mps"]),
            direction=str(s["direction"]),
            battery_v=float(s["battery_v"]),
            track_m=float(s["track_m"]),
            fix_quality=s["fix_quality"],
        )
        for s in samples
    )
    rail_m = dry_run.rail_length_m
    analysis = analyse_columns(
        columns, segments=dry_run.segments, rail_length_m=rail_m, pass_at_m=pass_at_m
    )
    series = chart_series(
        columns, segments=dry_run.segments, rail_length_m=rail_m, max_points=max_points
    )
    return RunReport(analysis, series, dry_run.started_at if samples else None)


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


def _samples_json_head(run: Run) -> bytes:
    head = {
        "run": run.pk,
        "title": run.title,
        "resource": run.resource.name,
        "state": run.state,
        "segments": run.segments,
        "rail_length_m": run.rail_length_m,
    }
    return (json.dumps(head)[:-1] + ', "samples": [').encode()


def run_samples_json(*, run: Run, chunk_rows: int = 2000) -> Iterator[bytes]:
    """Every sample of a run as one JSON document (UTF-8), streamed in chunks (never built
    whole); each sample an object of the contract's columns, times as in the CSV.

    On PostgreSQL the database writes each sample's JSON values (``COPY … TO STDOUT``, as
    cheap for it as the CSV); here its fields are put between the objects' literal pieces.
    """
    yield _samples_json_head(run)
    if sql.is_postgresql():
        pieces = queries.SAMPLE_JSON_PIECES
        heads, close = pieces[:-1], pieces[-1]
        columns = len(heads)
        first = True
        for chunk in queries.samples_json_copy(run.pk):
            # COPY's text format escapes only backslashes here (JSON text holds no raw tab,
            # newline or other control character): undo that; then split the chunk's whole
            # rows into fields and put each column's piece before its field, all in C (list
            # slices and one join: a few nanoseconds a field).
            if b"\\" in chunk:
                chunk = chunk.replace(b"\\\\", b"\\")
            fields = chunk.replace(b"\n", b"\t").split(b"\t")
            fields.pop()  # after the last row's newline
            if len(fields) % columns:
                raise RuntimeError("COPY handed over a partial row")
            joined = [b""] * (2 * len(fields))
            joined[0::2] = heads * (len(fields) // columns)
            joined[1::2] = fields
            text = b"".join(joined)
            yield text[2:] if first else text  # the first object has nothing to close
            first = False
        yield b"]}" if first else close + b"]}"
        return
    qs = Sample.objects.filter(run=run).order_by("seq").values(*SAMPLE_FIELDS)
    batch: list[str] = []
    first = True
    for record in qs.iterator(chunk_size=chunk_rows):
        record["t"] = record["t"].astimezone(UTC).strftime(CSV_TIME_FORMAT)
        batch.append(json.dumps(record))
        if len(batch) == chunk_rows:
            yield (("" if first else ",") + ",".join(batch)).encode()
            first, batch = False, []
    if batch:
        yield (("" if first else ",") + ",".join(batch)).encode()
    yield b"]}"


# The newest self-checks a robot's page and the API list.
SELF_CHECKS_LISTED = 100


def self_checks_of(robot: Resource) -> list[SelfCheck]:
    """A robot's self-checks, newest first (at most SELF_CHECKS_LISTED), with their runs."""
    return list(
        SelfCheck.objects.filter(resource=robot)
        .select_related("run", "resource")
        .order_by("-created_at", "-pk")[:SELF_CHECKS_LISTED]
    )


def self_check_baseline_of(robot: Resource) -> SelfCheckBaseline | None:
    return SelfCheckBaseline.objects.filter(resource=robot).first()


def self_check_schedule_of(robot: Resource) -> SelfCheckSchedule | None:
    return SelfCheckSchedule.objects.filter(resource=robot).select_related("set_by").first()
