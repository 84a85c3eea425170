"""A researcher's own measurements on a run: stored, placed on the robot's path, summed up.

One service for every door (the run page's upload, ``/api/v1/runs/{id}/measurements/``, the
``amazing measurements`` command, live batches during the run): :func:`measurement_add`
checks the points against the run, stores those not stored yet (a point is its series,
column and time: sent twice, stored once), and makes the series's summary again from every
point it holds, placed on the run's samples (``placement.py``, ``measurement_summary.py``).
Who may is the caller's ``runs_visible`` (the run's owner and staff); the audit log records
each change with the door it came through.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any, Final

import numpy as np
import psycopg
from django.conf import settings
from django.db import IntegrityError, transaction
from django.utils.text import slugify

from core import sql
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import InvalidInput
from core.events.services import event_record
from portal.runs import queries
from portal.runs.measurement_files import (
    MeasurementFileError,
    Points,
    read_points,
    rows_table,
    table_points,
)
from portal.runs.measurement_summary import column_summary
from portal.runs.models import MeasurementPoint, MeasurementSeries, Run, Sample
from portal.runs.placement import Track, place

# Points further than this from the run's window cannot be the run's: most likely a column
# in milliseconds, or a year typed wrong. (Within it, points outside the window are kept and
# marked "before" or "after".)
SENSE_S: Final = 7 * 24 * 3600.0
MAX_CLOCK_OFFSET_S: Final = 24 * 3600.0
MAX_SERIES_POINTS: Final = 5_000_000
MAX_SERIES_PER_RUN: Final = 50


class MeasurementRefused(InvalidInput):
    """Bad points or a bad series description: nothing was stored."""


@dataclass(frozen=True)
class Added:
    """What an upload did: the series, the points new to it, those it held already."""

    series: MeasurementSeries
    created: bool
    stored: int
    already: int


def _refuse(field: str, message: str) -> MeasurementRefused:
    return MeasurementRefused(message, fields={field: [message]})


def series_name(name: str) -> str:
    """A series's name as stored: a slug (``rssi``, ``iperf-up``)."""
    slug = slugify(name)
    if not slug or slug != name.strip().lower() or len(slug) > 64:
        raise _refuse(
            "name",
            "a series's name is letters, digits, '-' and '_' only (at most 64), "
            f"for example {slug or 'rssi'!r}",
        )
    return slug


def _checked_points(run: Run, points: Points, offset_s: float) -> None:
    if len(points) > MAX_SERIES_POINTS:
        raise _refuse("file", f"at most {MAX_SERIES_POINTS:,} points in a series")
    if not np.isfinite(offset_s) or abs(offset_s) > MAX_CLOCK_OFFSET_S:
        raise _refuse("clock_offset_s", f"a clock offset is within ±{MAX_CLOCK_OFFSET_S:g} s")
    shifted = points.times_s + offset_s
    low_s = run.start_at.timestamp() - SENSE_S
    high_s = run.end_at.timestamp() + SENSE_S
    outside = (shifted < low_s) | (shifted > high_s)
    if outside.any():
        row = int(np.flatnonzero(outside)[0])
        at = datetime.fromtimestamp(float(shifted[row]), UTC) if abs(shifted[row]) < 1e11 else None
        raise _refuse(
            "file",
            f"row {row + 1}: the time {at.isoformat() if at else repr(float(points.times_s[row]))} "
            "is more than 7 days from the run: are the times in seconds (not milliseconds), "
            "and of this run?",
        )
    order = np.argsort(points.times_s, kind="stable")
    repeated = np.flatnonzero(np.diff(np.rint(points.times_s[order] * 1e6)) == 0)
    if len(repeated):
        first, second = sorted((int(order[repeated[0]]), int(order[repeated[0] + 1])))
        raise _refuse("file", f"rows {first + 1} and {second + 1} have the same time")


def store_column(
    series: MeasurementSeries, index: int, times_us: np.ndarray, values: np.ndarray
) -> int:
    """Store one column's points (those with a value); how many were new."""
    keep = ~np.isnan(values)
    times_us, values = times_us[keep], values[keep]
    if len(times_us) == 0:
        return 0
    if sql.is_postgresql():
        try:
            # Straight in when none is stored yet (the first upload, a later live batch):
            # as fast as COPY itself. A point stored already fails it whole: merged then.
            with transaction.atomic():
                queries.measurement_points_copy(series.pk, index, times_us, values)
            return len(times_us)
        except (IntegrityError, psycopg.errors.UniqueViolation):
            return queries.measurement_points_merge(series.pk, index, times_us, values)
    rows = [
        MeasurementPoint(
            series=series,
            column_index=index,
            t=datetime.fromtimestamp(int(t_us) / 1e6, UTC),
            value=float(value),
        )
        for t_us, value in zip(times_us, values, strict=True)
    ]
    before = MeasurementPoint.objects.filter(series=series, column_index=index).count()
    MeasurementPoint.objects.bulk_create(rows, batch_size=2000, ignore_conflicts=True)
    return MeasurementPoint.objects.filter(series=series, column_index=index).count() - before


def series_points(series: MeasurementSeries) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every stored point of the series: per column, its times (Unix seconds, on the
    researcher's clock) and values, in time order."""
    if sql.is_postgresql():
        columns, times_us, values = queries.measurement_points_read(series.pk)
    else:
        rows = list(
            MeasurementPoint.objects.filter(series=series)
            .order_by("column_index", "t")
            .values_list("column_index", "t", "value")
        )
        columns = np.array([row[0] for row in rows], dtype=np.int64)
        times_us = np.array([round(row[1].timestamp() * 1e6) for row in rows], dtype=np.int64)
        values = np.array([row[2] for row in rows], dtype=np.float64)
    out = []
    for index in range(len(series.columns)):
        mine = columns == index
        out.append((times_us[mine] / 1e6, values[mine]))
    return out


def run_track(run: Run) -> Track:
    """The run's samples as placement reads them."""
    rows = list(
        Sample.objects.filter(run=run)
        .order_by("seq")
        .values_list(
            "seq",
            "t",
            "track_m",
            "segment",
            "lap",
            "commanded_velocity_mps",
            "velocity_mps",
            "lat_deg",
            "lon_deg",
            "grid_id",
        )
    )

    def column(i: int) -> np.ndarray:
        return np.array([np.nan if row[i] is None else row[i] for row in rows], dtype=np.float64)

    return Track(
        seq=np.array([row[0] for row in rows], dtype=np.int64),
        t_s=np.array([row[1].timestamp() for row in rows], dtype=np.float64),
        track_m=column(2),
        segment=column(3),
        lap=column(4),
        commanded_velocity_mps=column(5),
        velocity_mps=column(6),
        lat_deg=column(7),
        lon_deg=column(8),
        grid_id=[row[9] for row in rows],
        rail_length_m=run.rail_length_m,
    )


def summary_of(series: MeasurementSeries, track: Track | None = None) -> dict[str, Any]:
    """The series placed on its run's path, per column (``measurement_summary``)."""
    run = series.run
    track = track if track is not None else run_track(run)
    columns: dict[str, Any] = {}
    per_column = series_points(series)
    every_time_us = [np.rint(times_s * 1e6).astype(np.int64) for times_s, _ in per_column]
    times_seen = np.unique(np.concatenate([np.zeros(0, np.int64), *every_time_us]))
    for name, (times_s, values) in zip(series.columns, per_column, strict=True):
        shifted = times_s + series.clock_offset_s
        columns[name] = column_summary(
            shifted, values, place(shifted, track), start_s=run.start_at.timestamp()
        )
    event_s = first_segment_start_s(track)
    return {
        "columns": columns,
        "points": len(times_seen),
        "clock_offset_s": series.clock_offset_s,
        "samples": len(track.seq),
        # The robot's first segment began then (base station's clock); with the series's
        # marker of that moment (its own clock), the offset that aligns the two.
        "first_segment_at_s": event_s,
        "suggested_offset_s": (
            suggested_offset_s(marker_s=series.marker_at.timestamp(), robot_event_s=event_s)
            if series.marker_at is not None and event_s is not None
            else None
        ),
    }


def first_segment_start_s(track: Track) -> float | None:
    """When the run's first program segment began: its first sample's time."""
    started = np.flatnonzero(track.segment == 0)
    return float(track.t_s[started[0]]) if len(started) else None


def _measured_event(
    series: MeasurementSeries, *, change: str, stored: int = 0, via: str = ""
) -> None:
    """The change as an event for the run's owner, in the change's transaction: the run page
    and its roof view redraw the series live (``portal/web/handlers.py``), webhooks hear it."""
    reservation_id, owner_id, resource = (
        Run.objects.filter(pk=series.run_id)
        .values_list("reservation_id", "reservation__owner_id", "resource__name")
        .get()
    )
    event_record(
        subject=f"run:{series.run_id}",
        type="run.measured",
        owner_id=owner_id,
        payload={
            "run": series.run_id,
            "reservation": reservation_id,
            "resource": resource,
            "series": series.name,
            "change": change,
            "points": series.point_count if change != "deleted" else 0,
            "stored": stored,
            "via": via,
        },
    )


def _refresh(series: MeasurementSeries) -> None:
    series.summary = summary_of(series)
    series.point_count = int(series.summary["points"])
    series.save(update_fields=["summary", "point_count", "updated_at"])


def _locked_series(run: Run, name: str, points: Points, by: User) -> tuple[Run, MeasurementSeries]:
    """The run and its series ``name``, locked; a new series (not saved yet) if there is
    none. The run's row serialises the series made on it (their number is capped)."""
    locked_run = Run.objects.select_for_update().get(pk=run.pk)
    series = MeasurementSeries.objects.select_for_update().filter(run=run, name=name).first()
    if series is None:
        if MeasurementSeries.objects.filter(run=run).count() >= MAX_SERIES_PER_RUN:
            raise _refuse("name", f"a run holds at most {MAX_SERIES_PER_RUN} series")
        return locked_run, MeasurementSeries(
            run=locked_run, name=name, columns=list(points.columns), created_by=by
        )
    if list(series.columns) != list(points.columns):
        raise _refuse(
            "file",
            f"the series {name!r} has the columns {', '.join(series.columns)}; "
            f"these points have {', '.join(points.columns)}",
        )
    return locked_run, series


def measurement_add(
    *,
    run: Run,
    by: User,
    name: str,
    points: Points,
    unit: str = "",
    description: str = "",
    source_node: str = "",
    clock_offset_s: float | None = None,
    marker_at: datetime | None = None,
    ip: str | None = None,
    via: str = "",
) -> Added:
    """Add ``points`` to the run's series ``name`` (made on first use, with ``points``'s
    columns): the points not stored yet are stored, and the summary made again. A series
    given again with other columns is refused; ``clock_offset_s`` given changes the
    series's offset."""
    name = series_name(name)
    with transaction.atomic():
        locked_run, series = _locked_series(run, name, points, by)
        created = series.pk is None
        offset_s = series.clock_offset_s if clock_offset_s is None else float(clock_offset_s)
        _checked_points(locked_run, points, offset_s)
        if series.point_count + len(points) > MAX_SERIES_POINTS:
            raise _refuse("file", f"at most {MAX_SERIES_POINTS:,} points in a series")
        placed_again = not created and offset_s != series.clock_offset_s
        series.clock_offset_s = offset_s
        _described(
            series,
            unit=unit,
            description=description,
            source_node=source_node,
            marker_at=marker_at,
        )
        series.save()
        times_us = np.rint(points.times_s * 1e6).astype(np.int64)
        stored = 0
        for index, values in enumerate(points.values):
            stored += store_column(series, index, times_us, values)
        _refresh(series)
        if stored or created or placed_again:  # the same points again: no one is told
            change = "added" if stored or created else "placed"
            _measured_event(series, change=change, stored=stored, via=via)
        total = sum(int(np.count_nonzero(~np.isnan(values))) for values in points.values)
        audit_record(
            actor=by,
            action="measurement.add",
            target=series,
            ip=ip,
            via=via,
            run=run.pk,
            name=name,
            values_stored=stored,
            values_already=total - stored,
            digest=_digest(times_us, points.values),
        )
    return Added(series=series, created=created, stored=stored, already=total - stored)


def _described(
    series: MeasurementSeries,
    *,
    unit: str,
    description: str,
    source_node: str,
    marker_at: datetime | None,
) -> None:
    """What an upload says of its series, set on it (what it leaves empty is kept)."""
    if len(unit) > 32 or len(source_node) > 64 or len(description) > 2000:
        raise _refuse("unit", "unit at most 32 characters, source node 64, description 2000")
    if marker_at is not None:
        _check_marker(series.run, marker_at)
        series.marker_at = marker_at
    for field, given in (
        ("unit", unit),
        ("description", description),
        ("source_node", source_node),
    ):
        if given:
            setattr(series, field, given)


def _digest(times_us: np.ndarray, values: list[np.ndarray]) -> str:
    """A fingerprint of the points, for the audit log (the same upload twice: one digest)."""
    digest = hashlib.sha256(times_us.tobytes())
    for column in values:
        digest.update(column.tobytes())
    return digest.hexdigest()[:16]


def measurement_update(
    *,
    series: MeasurementSeries,
    by: User,
    clock_offset_s: float | None = None,
    marker_at: datetime | None = None,
    ip: str | None = None,
    via: str = "",
) -> MeasurementSeries:
    """Set the series's clock offset, or its marker (when the measuring machine saw the first
    segment begin), or both; its points are placed again."""
    if clock_offset_s is not None and (
        not np.isfinite(clock_offset_s) or abs(clock_offset_s) > MAX_CLOCK_OFFSET_S
    ):
        raise _refuse("clock_offset_s", f"a clock offset is within ±{MAX_CLOCK_OFFSET_S:g} s")
    with transaction.atomic():
        locked = (
            MeasurementSeries.objects.select_for_update().select_related("run").get(pk=series.pk)
        )
        if marker_at is not None:
            _check_marker(locked.run, marker_at)
        before = {"clock_offset_s": locked.clock_offset_s, "marker_at": _iso(locked.marker_at)}
        if clock_offset_s is not None:
            locked.clock_offset_s = float(clock_offset_s)
        if marker_at is not None:
            locked.marker_at = marker_at
        locked.save(update_fields=["clock_offset_s", "marker_at", "updated_at"])
        _refresh(locked)
        _measured_event(locked, change="placed", via=via)
        audit_record(
            actor=by,
            action="measurement.update",
            target=locked,
            ip=ip,
            via=via,
            run=locked.run_id,
            before=before,
            after={"clock_offset_s": locked.clock_offset_s, "marker_at": _iso(locked.marker_at)},
        )
    return locked


def _iso(value: datetime | None) -> str | None:
    return value.isoformat() if value is not None else None


def _check_marker(run: Run, marker_at: datetime) -> None:
    low_s = run.start_at.timestamp() - SENSE_S
    high_s = run.end_at.timestamp() + SENSE_S
    if not low_s <= marker_at.timestamp() <= high_s:
        raise _refuse("marker_at", "the marker is more than 7 days from the run")


def measurement_delete(
    *, series: MeasurementSeries, by: User, ip: str | None = None, via: str = ""
) -> None:
    """Delete the series and its points."""
    with transaction.atomic():
        audit_record(
            actor=by,
            action="measurement.delete",
            target=series,
            ip=ip,
            via=via,
            run=series.run_id,
            name=series.name,
            points=series.point_count,
        )
        _measured_event(series, change="deleted", via=via)
        MeasurementPoint.objects.filter(series=series).delete()
        series.delete()


def suggested_offset_s(*, marker_s: float, robot_event_s: float) -> float:
    """The offset that puts a series's marker (a time on the researcher's clock) on a known
    robot event (a time on the base station's clock, for example the first segment's start):
    the two are the same moment, so the offset is the clocks' difference then."""
    return round(robot_event_s - marker_s, 6)


def read_file_points(
    data: bytes, fmt: str, *, time_column: str = "", columns: list[str] | None = None
) -> Points:
    """``measurement_files.read_points``, its errors as the services' (a 400 with the
    field ``file``)."""
    try:
        return read_points(data, fmt, time_column=time_column, columns=columns)
    except MeasurementFileError as exc:
        raise _refuse("file", str(exc)) from None


def rows_points(rows: list[dict[str, Any]]) -> Points:
    """An API batch's points (objects with a time and values), its errors as the services'
    (a 400 with the field ``points``)."""
    try:
        return table_points(rows_table(rows))
    except MeasurementFileError as exc:
        raise _refuse("points", str(exc)) from None


def max_upload_bytes() -> int:
    """The largest measurement file taken (``MEASUREMENT_MAX_UPLOAD_BYTES``)."""
    return int(settings.MEASUREMENT_MAX_UPLOAD_BYTES)


__all__ = [
    "Added",
    "MeasurementRefused",
    "clock_state",
    "measurement_add",
    "measurement_delete",
    "measurement_update",
    "read_file_points",
    "rows_points",
    "run_track",
    "series_points",
    "store_column",
    "suggested_offset_s",
    "summary_of",
]


def clock_state(provenance: Any) -> str:
    """The base station's clock over the run, in words, from its provenance: what a series's
    times are compared with."""
    collected = (provenance or {}).get("collected") or {}
    said = []
    for when in ("start", "end"):
        clock = collected.get(f"clock_at_{when}") or {}
        synchronized = clock.get("synchronized")
        state = (
            "synchronised"
            if synchronized is True
            else "not synchronised"
            if synchronized is False
            else "unknown"
        )
        if clock.get("offset_s") is not None:
            state += f" (offset {clock['offset_s']:.6f} s)"
        said.append(f"at {when} {state}")
    if not collected:
        return "not recorded yet (it is, when the run is collected)"
    return ", ".join(said)
