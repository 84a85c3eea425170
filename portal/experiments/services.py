"""Writes for experiments and runs: validation of programs, run state changes, data ingest."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping
from datetime import UTC, datetime
from typing import Any

import psycopg
from django.db import IntegrityError, connection, transaction
from django.db.models import Count, Max
from django.utils import timezone
from django.utils.dateparse import parse_datetime

from portal.accounts.models import User
from portal.errors import InvalidInput
from portal.experiments.choices import Direction, RunState
from portal.experiments.models import SAMPLE_FIELDS, Experiment, Run, RunEvent, Sample

logger = logging.getLogger(__name__)

MAX_SEGMENTS = 100
MAX_PROGRAM_S = 24 * 3600.0
SEGMENT_KEYS = {"velocity_mps", "direction", "duration_s"}


def segments_validate(
    segments: Any, *, max_velocity_mps: float | None = None
) -> list[dict[str, Any]]:
    """A clean copy of a program, or ``InvalidInput`` naming the segment and field at fault."""
    if not isinstance(segments, list) or not segments:
        raise InvalidInput.on_field("segments", "An experiment needs at least one segment.")
    if len(segments) > MAX_SEGMENTS:
        raise InvalidInput.on_field("segments", f"At most {MAX_SEGMENTS} segments.")
    errors: list[str] = []
    clean: list[dict[str, Any]] = []
    for i, raw in enumerate(segments, start=1):
        if not isinstance(raw, Mapping):
            errors.append(f"Segment {i}: must be an object with {sorted(SEGMENT_KEYS)}.")
            continue
        unknown = set(raw) - SEGMENT_KEYS
        missing = SEGMENT_KEYS - set(raw)
        if unknown or missing:
            parts = []
            if missing:
                parts.append(f"missing {', '.join(sorted(missing))}")
            if unknown:
                parts.append(f"unknown {', '.join(sorted(unknown))}")
            errors.append(f"Segment {i}: {'; '.join(parts)}.")
            continue
        velocity = _number(raw["velocity_mps"])
        duration = _number(raw["duration_s"])
        direction = raw["direction"]
        if velocity is None or velocity < 0:
            errors.append(f"Segment {i}: velocity must be a number ≥ 0 m/s.")
        elif max_velocity_mps is not None and velocity > max_velocity_mps:
            errors.append(
                f"Segment {i}: velocity {velocity:g} m/s exceeds the maximum "
                f"{max_velocity_mps:g} m/s of this robot."
            )
        if direction not in Direction.values:
            errors.append(f"Segment {i}: direction must be 'cw' or 'ccw'.")
        if duration is None or duration <= 0:
            errors.append(f"Segment {i}: duration must be a number > 0 s.")
        if not errors:
            clean.append({"velocity_mps": velocity, "direction": direction, "duration_s": duration})
    if errors:
        raise InvalidInput(errors[0], fields={"segments": errors})
    total_s = sum(s["duration_s"] for s in clean)
    if total_s > MAX_PROGRAM_S:
        raise InvalidInput.on_field(
            "segments", f"The program lasts {total_s:g} s; at most {MAX_PROGRAM_S:g} s."
        )
    return clean


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        return None
    try:
        number = float(value)
    except ValueError:
        return None
    return number if math.isfinite(number) else None


def _title_validate(title: Any) -> str:
    if not isinstance(title, str) or not title.strip():
        raise InvalidInput.on_field("title", "A title is required.")
    if len(title) > 200:
        raise InvalidInput.on_field("title", "At most 200 characters.")
    return title.strip()


def experiment_create(*, owner: User, title: str, segments: Any) -> Experiment:
    from bookings.selectors import mobile_max_velocity_mps

    experiment = Experiment(
        owner=owner,
        title=_title_validate(title),
        segments=segments_validate(segments, max_velocity_mps=mobile_max_velocity_mps()),
    )
    experiment.full_clean()
    experiment.save()
    return experiment


def experiment_update(*, experiment: Experiment, title: str, segments: Any) -> Experiment:
    from bookings.selectors import mobile_max_velocity_mps

    experiment.title = _title_validate(title)
    experiment.segments = segments_validate(segments, max_velocity_mps=mobile_max_velocity_mps())
    experiment.full_clean()
    experiment.save()
    return experiment


def run_transition(
    *, run_id: int, from_states: Iterable[str], to_state: str, reason: str = ""
) -> bool:
    """Move a run to ``to_state`` if it is in one of ``from_states``; False if it was not.

    A compare-and-set update, so two workers racing on the same run change it once, and a
    task that finds the run already past its step does nothing.
    """
    from_states = tuple(from_states)
    with transaction.atomic():
        current = (
            Run.objects.select_for_update()
            .filter(pk=run_id, state__in=from_states)
            .values_list("state", flat=True)
            .first()
        )
        if current is None:
            return False
        Run.objects.filter(pk=run_id).update(
            state=to_state, reason=reason, updated_at=timezone.now()
        )
        RunEvent.objects.create(run_id=run_id, from_state=current, to_state=to_state, reason=reason)
    logger.info("run %s: %s → %s %s", run_id, current, to_state, reason)
    return True


def samples_ingest(*, run: Run, samples: list[dict[str, Any]]) -> int:
    """Store a page of samples from the agent; duplicates (same run and seq) are skipped.

    Returns how many rows the page held. ``run.last_seq`` only moves forward. On PostgreSQL
    the page goes in by ``COPY`` into a temporary table and one ``INSERT … ON CONFLICT DO
    NOTHING``: several times faster than row inserts, and still idempotent.
    """
    if not samples:
        return 0
    rows = [
        (
            int(s["seq"]),
            _epoch_to_datetime(s["t"]),
            s.get("segment"),
            float(s["commanded_velocity_mps"]),
            float(s["velocity_mps"]),
            str(s["direction"]),
            float(s["battery_v"]),
            float(s["track_m"]),
            s.get("fix_quality"),
            s.get("lat_deg"),
            s.get("lon_deg"),
            s.get("grid_id"),
            s.get("lap"),
        )
        for s in samples
    ]
    last_seq = max(r[0] for r in rows)
    with transaction.atomic():
        if connection.vendor == "postgresql":
            _copy_samples(run.pk, rows)
        else:
            Sample.objects.bulk_create(
                [Sample(run=run, **dict(zip(SAMPLE_FIELDS, r, strict=True))) for r in rows],
                batch_size=2000,
                ignore_conflicts=True,
            )
        Run.objects.filter(pk=run.pk, last_seq__lt=last_seq).update(last_seq=last_seq)
    run.last_seq = max(run.last_seq, last_seq)
    return len(rows)


def _copy_samples(run_id: int, rows: list[tuple[Any, ...]]) -> None:
    """COPY straight into the table; if a row is already there (a repeated or overlapping
    collection), roll that back and merge through a temporary table instead."""
    columns = ", ".join(SAMPLE_FIELDS)
    table = Sample._meta.db_table
    try:
        with (
            transaction.atomic(),
            connection.cursor() as cursor,
            cursor.copy(f"COPY {table} (run_id, {columns}) FROM STDIN") as copy,
        ):
            for row in rows:
                copy.write_row((run_id, *row))
        return
    except (IntegrityError, psycopg.errors.UniqueViolation):
        # COPY goes to psycopg directly, so its error arrives unwrapped by Django. The unique
        # (run, seq) constraint saw a duplicate and the savepoint undid the whole page.
        pass
    with connection.cursor() as cursor:
        # Emptied at every commit, so one per connection serves every page.
        cursor.execute(
            "CREATE TEMPORARY TABLE IF NOT EXISTS sample_page (seq integer, t timestamptz, "
            "segment smallint, commanded_velocity_mps double precision, "
            "velocity_mps double precision, direction varchar(3), battery_v double precision, "
            "track_m double precision, fix_quality smallint, lat_deg double precision, "
            "lon_deg double precision, grid_id varchar(8), lap integer) ON COMMIT DELETE ROWS"
        )
        with cursor.copy(f"COPY sample_page ({columns}) FROM STDIN") as copy:
            for row in rows:
                copy.write_row(row)
        # Identifiers are this module's constants; the run id is a bound parameter.
        cursor.execute(
            f"INSERT INTO {table} (run_id, {columns}) SELECT %s, {columns} FROM sample_page "  # noqa: S608
            "ON CONFLICT (run_id, seq) DO NOTHING",
            [run_id],
        )


def _epoch_to_datetime(value: Any) -> datetime:
    if isinstance(value, int | float):
        return datetime.fromtimestamp(float(value), tz=UTC)
    parsed = parse_datetime(str(value))
    if parsed is None:
        raise ValueError(f"not a timestamp: {value!r}")
    return parsed


def run_sample_stats(*, run: Run) -> dict[str, int]:
    stats = Sample.objects.filter(run=run).aggregate(count=Count("pk"), last_seq=Max("seq"))
    return {"count": stats["count"] or 0, "last_seq": stats["last_seq"] or 0}


def run_create(*, reservation: Any, resource: Any, experiment: Experiment) -> Run:
    """The run of ``experiment`` on ``resource`` in a just-made reservation (``scheduled``)."""
    run = Run(
        reservation=reservation,
        resource=resource,
        experiment=experiment,
        title=experiment.title,
        segments=experiment.segments,
        start_at=reservation.start_at,
        end_at=reservation.end_at,
        state=RunState.SCHEDULED,
    )
    run.full_clean(exclude=["reservation", "resource"])
    run.save()
    RunEvent.objects.create(run=run, from_state="", to_state=RunState.SCHEDULED, reason="booked")
    return run
