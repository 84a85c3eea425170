"""A measurement series of a million points: stored, placed, summed up, shown.

DESIGN of the measurements (docs/measurements.md): a series of one million points (per-packet
RSSI at about 280 Hz for an hour) is stored at no less than half the speed of a plain
``COPY`` of the same rows into a table of the same shape, placed on the run's samples (an hour
at 20 Hz) within a second, and its part of the run page is made within 0.3 s. Each is
measured here beside its baseline in the same run: the CSV ``COPY`` that ``psql``'s ``\\copy``
does, into a copy of the points table with its key.
"""

from __future__ import annotations

import statistics
import time
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np

POINTS = 1_000_000
SAMPLES = 72_000
REPEATS = 3
SAMPLE_HZ = 20.0


def _run_with_samples(samples: int) -> Any:
    from bookings.choices import ResourceKind
    from bookings.models import Reservation, Resource
    from core.accounts.models import User
    from portal.experiments.models import Experiment
    from portal.runs.models import Run
    from portal.runs.services.collection import samples_ingest

    owner = User.objects.create_user(username="measurer")
    robot = Resource.objects.create(name="mobile-1", kind=ResourceKind.MOBILE)
    duration_s = samples / SAMPLE_HZ
    segments = [{"velocity_mps": 0.8, "direction": "cw", "duration_s": duration_s}]
    experiment = Experiment.objects.create(owner=owner, title="an hour", segments=segments)
    start = datetime.now(UTC).replace(microsecond=0) - timedelta(seconds=duration_s + 60)
    end = start + timedelta(seconds=duration_s + 30)
    reservation = Reservation.objects.create(owner=owner, start_at=start, end_at=end)
    run = Run.objects.create(
        reservation=reservation, resource=robot, experiment=experiment, title="an hour",
        segments=segments, start_at=start, end_at=end, rail_length_m=120.0,
    )  # fmt: skip
    t0_s = start.timestamp()
    page = []
    for seq in range(1, samples + 1):
        t_s = (seq - 1) / SAMPLE_HZ
        track_m = (0.8 * t_s) % 120.0
        page.append(
            {
                "seq": seq, "t": t0_s + t_s, "segment": 0, "commanded_velocity_mps": 0.8,
                "velocity_mps": 0.8, "direction": "cw", "battery_v": 60.0, "track_m": track_m,
                "fix_quality": 4, "lat_deg": 40.63, "lon_deg": -8.66,
                "grid_id": f"{'ABCD'[int(track_m // 30)]}{int(track_m % 30 // 7.5) + 1}",
                "lap": int(0.8 * t_s // 120.0),
            }
        )  # fmt: skip
        if len(page) == 5000:
            samples_ingest(run=run, samples=page)
            page = []
    if page:
        samples_ingest(run=run, samples=page)
    return run, owner


def _reference_copy(rows_csv: bytes) -> float:
    """The baseline: the same rows by a CSV ``COPY`` into a table like the points table."""
    from django.db import connection

    with connection.cursor() as cursor:
        cursor.execute("DROP TABLE IF EXISTS bench_points")
        cursor.execute("CREATE TABLE bench_points (LIKE runs_measurementpoint INCLUDING ALL)")
        started = time.perf_counter()
        with cursor.copy(
            "COPY bench_points (series_id, column_index, t, value) FROM STDIN (FORMAT csv)"
        ) as copy:
            copy.write(rows_csv)
        return time.perf_counter() - started


def _points(run: Any, points: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(11)
    span_s = (run.end_at - run.start_at).total_seconds() - 30
    times_s = run.start_at.timestamp() + np.sort(rng.uniform(0, span_s, points))
    times_s = np.unique(np.round(times_s, 6))
    return times_s, rng.normal(-60.0, 4.0, len(times_s))


def _csv(series_id: int, times_s: np.ndarray, values: np.ndarray) -> bytes:
    stamps = np.datetime_as_string((times_s * 1e6).astype("datetime64[us]"), unit="us")
    lines = [f"{series_id},0,{t}Z,{v!r}\n" for t, v in zip(stamps, values.tolist(), strict=True)]
    return "".join(lines).encode()


def run(*, points: int = POINTS, samples: int = SAMPLES, repeats: int = REPEATS) -> str:
    from django.conf import settings
    from django.db import connection, transaction
    from django.template.loader import render_to_string
    from django.urls import get_resolver

    # The URL configuration first, as the web server loads it: its imports' order is the one
    # the portal's modules are written for.
    get_resolver().url_patterns  # noqa: B018

    from portal.runs import measurements
    from portal.runs.measurement_files import Points
    from portal.runs.measurement_summary import column_summary
    from portal.runs.models import MeasurementPoint, MeasurementSeries
    from portal.runs.placement import place
    from portal.web.views import measurements_context

    settings.DEBUG = False
    run_, owner = _run_with_samples(samples)
    times_s, values = _points(run_, points)
    n = len(times_s)
    times_us = np.rint(times_s * 1e6).astype(np.int64)
    stored_s, reference_s, added_s = [], [], []
    for _ in range(repeats):
        series = MeasurementSeries.objects.create(run=run_, name="rssi", columns=["rssi"])
        rows_csv = _csv(series.pk, times_s, values)
        reference_s.append(_reference_copy(rows_csv))
        with transaction.atomic():
            started = time.perf_counter()
            measurements.store_column(series, 0, times_us, values)
            stored_s.append(time.perf_counter() - started)
        MeasurementPoint.objects.filter(series=series).delete()
        series.delete()
        with connection.cursor() as cursor:
            cursor.execute("DROP TABLE IF EXISTS bench_points")
        started = time.perf_counter()
        added = measurements.measurement_add(
            run=run_, by=owner, name="rssi", unit="dBm",
            points=Points(times_s=times_s, columns=["rssi"], values=[values]),
        )  # fmt: skip
        added_s.append(time.perf_counter() - started)
        assert added.stored == n
        if len(added_s) < repeats:
            MeasurementPoint.objects.filter(series=added.series).delete()
            added.series.delete()
    started = time.perf_counter()
    track = measurements.run_track(run_)
    track_s = time.perf_counter() - started
    place_s, summary_s, page_s = [], [], []
    for _ in range(repeats):
        started = time.perf_counter()
        placed = place(times_s, track)
        place_s.append(time.perf_counter() - started)
        started = time.perf_counter()
        column_summary(times_s, values, placed, start_s=run_.start_at.timestamp())
        summary_s.append(time.perf_counter() - started)
        started = time.perf_counter()
        html = render_to_string(
            "web/_run_measurements.html", {"run": run_, **measurements_context(run_, None)}
        )
        page_s.append(time.perf_counter() - started)
        assert "rssi per grid cell" in html
    stored = statistics.median(stored_s)
    reference = statistics.median(reference_s)
    rows = [
        ("stored (the service's binary COPY)", stored, f"{n / stored:,.0f} points/s"),
        ("baseline: CSV COPY of the same rows", reference, f"{n / reference:,.0f} points/s"),
        ("added whole (stored, read back, placed, summed up)", statistics.median(added_s), ""),
        (f"the run's {samples:,} samples read for placing", track_s, ""),
        ("placed on the samples", statistics.median(place_s), ""),
        ("summed up (per metre, per cell, downsampled)", statistics.median(summary_s), ""),
        ("the run page's measurements section made", statistics.median(page_s), ""),
    ]
    table = "\n".join(f"| {what} | {seconds:.3f} s | {rate} |" for what, seconds, rate in rows)
    return (
        f"## A series of {n:,} points on a run of {samples:,} samples\n\n"
        "| step | median time | rate |\n| --- | --- | --- |\n"
        f"{table}\n\n"
        f"Stored at **{reference / stored:.0%}** of the CSV `COPY`'s speed (target ≥ 50 %); "
        f"placed in **{statistics.median(place_s):.2f} s** (target ≤ 1 s); the page's part in "
        f"**{statistics.median(page_s):.3f} s** (target ≤ 0.3 s). Medians of {repeats}."
    )
