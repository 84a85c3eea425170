"""A researcher's measurement series: read from CSV, JSON and Parquet, checked against the run,
stored once, and placed on the run's samples (``portal/runs/measurements.py``)."""

from __future__ import annotations

import io
import json
from datetime import UTC, datetime

import jsonschema
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from core.audit.models import AuditEvent
from core.events.catalogue import EVENT_TYPES
from core.events.models import Event
from core.events.sequence import events_sequence
from portal.runs.measurement_files import format_of, read_points
from portal.runs.measurements import (
    MeasurementRefused,
    measurement_add,
    measurement_delete,
    measurement_update,
    read_file_points,
    suggested_offset_s,
)
from portal.runs.models import MeasurementPoint, MeasurementSeries, Sample
from tests.factories import UserFactory
from tests.runs.driving import CELL_M, run_round_the_rail

pytestmark = pytest.mark.django_db


def _iso(t_s: float) -> str:
    return datetime.fromtimestamp(t_s, UTC).isoformat().replace("+00:00", "Z")


def test_a_csv_with_rfc3339_or_unix_times_and_a_json_and_a_parquet_file_read_alike():
    times = [1795000000.25, 1795000000.5, 1795000001.0]
    csv_iso = "t,rssi\n" + "".join(f"{_iso(t)},{-60 - i}\n" for i, t in enumerate(times))
    csv_unix = "time,rssi\n" + "".join(f"{t},{-60 - i}\n" for i, t in enumerate(times))
    as_json = json.dumps([{"t": _iso(t), "rssi": -60 - i} for i, t in enumerate(times)])
    buffer = io.BytesIO()
    pq.write_table(
        pa.table(
            {
                "timestamp": pa.array(
                    [datetime.fromtimestamp(t, UTC) for t in times], pa.timestamp("us", tz="UTC")
                ),
                "rssi": [-60.0, -61.0, -62.0],
            }
        ),
        buffer,
    )
    read = [
        read_points(csv_iso.encode(), "csv"),
        read_points(csv_unix.encode(), "csv"),
        read_points(as_json.encode(), "json"),
        read_points(buffer.getvalue(), "parquet"),
    ]
    for points in read:
        assert points.columns == ["rssi"]
        np.testing.assert_allclose(points.times_s, times, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(points.values[0], [-60.0, -61.0, -62.0])
    assert format_of("walk.PARQUET") == "parquet"
    assert format_of("x", "csv") == "csv"


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("t,rssi\n2027-01-01T10:00:00,-60\n", "UTC offset"),
        ("t,rssi\n2027-01-01T10:00:00Z,-60\n2027-01-01T10:00:01Z,strong\n", "row 2"),
        ("when,rssi\n1795000000,-60\n", "no time column"),
        ("t,rssi\n", "no points"),
        ("t\n1795000000\n", "no value column"),
        ("t,rssi\nyesterday,-60\n", "row 1"),
    ],
)
def test_a_bad_file_is_refused_saying_where(text, said):
    with pytest.raises(MeasurementRefused) as refused:
        read_file_points(text.encode(), "csv")
    assert said in refused.value.message
    assert refused.value.fields == {"file": [refused.value.message]}


def test_an_unknown_column_or_format_is_named():
    with pytest.raises(MeasurementRefused, match="unknown value column 'snr'"):
        read_file_points(b"t,rssi\n1795000000,-60\n", "csv", columns=["snr"])
    with pytest.raises(ValueError, match=r"\.csv, \.json or \.parquet"):
        format_of("walk.xlsx")
    with pytest.raises(MeasurementRefused, match="not a readable JSON"):
        read_file_points(b"{nope", "json")
    picture = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\xff\xfe"
    for fmt in ("csv", "json", "parquet"):
        with pytest.raises(MeasurementRefused, match=f"not a readable {fmt.upper()}"):
            read_file_points(picture, fmt)


def test_points_are_placed_on_the_rail_and_summed_up_per_cell_and_metre():
    owner = UserFactory()
    run = run_round_the_rail(owner, speed_mps=2.0, seconds=30.0)
    t0_s = run.start_at.timestamp()
    # A point every 0.05 s, its value the position it was taken at (so each cell's mean is
    # known without the portal): track = 2 m/s * t.
    t_s = np.arange(0.0, 29.0, 0.05)
    text = "t,position\n" + "".join(f"{t0_s + t:.6f},{2.0 * t:.6f}\n" for t in t_s)
    points = read_file_points(text.encode(), "csv")
    added = measurement_add(run=run, by=owner, name="position", points=points, unit="m")
    assert added.created
    assert added.stored == len(t_s)
    assert added.already == 0
    summary = added.series.summary["columns"]["position"]
    assert summary["where"] == {"placed": len(t_s), "before": 0, "after": 0, "gap": 0}
    # The value is the position: every metre's mean lies in that metre, every cell's in it.
    for metre, count, mean, _std in summary["by_metre"]:
        assert count > 0
        assert metre <= mean < metre + 1.0 + 1e-9
    cells = {row["cell"]: row for row in summary["by_cell"]}
    # 58 m in 29 s: cells A1 to A6 (0-60 m), the nearer sample's cell for each point.
    assert list(cells) == ["A1", "A2", "A3", "A4", "A5", "A6"]
    for name, row in cells.items():
        low_m = (int(name[1:]) - 1) * CELL_M
        assert low_m - 0.2 <= row["min"] <= row["mean"] <= row["max"] <= low_m + CELL_M + 0.2
    assert len(summary["line"]["t_s"]) <= 1000
    assert summary["line"]["velocity_mps"][5] == 2.0


def test_the_same_file_twice_stores_once_and_another_clock_offset_moves_the_points():
    owner = UserFactory()
    run = run_round_the_rail(owner, seconds=10.0)
    t0_s = run.start_at.timestamp()
    text = "t,rssi,snr\n" + "".join(f"{t0_s + i * 0.5},{-50 - i},{20 + i}\n" for i in range(20))
    first = measurement_add(
        run=run, by=owner, name="rssi", points=read_file_points(text.encode(), "csv")
    )
    again = measurement_add(
        run=run, by=owner, name="rssi", points=read_file_points(text.encode(), "csv")
    )
    assert (first.stored, again.stored, again.already) == (40, 0, 40)
    assert MeasurementPoint.objects.filter(series=first.series).count() == 40
    assert again.series.point_count == 20
    digests = [e.data["digest"] for e in AuditEvent.objects.filter(action="measurement.add")]
    assert len(digests) == 2
    assert digests[0] == digests[1]
    # 10 s of samples: the last points (up to 9.5 s) are on the path; 5 s later they are after.
    moved = measurement_update(series=first.series, by=owner, clock_offset_s=5.0)
    where = moved.summary["columns"]["snr"]["where"]
    assert where["after"] == 10
    assert where["placed"] == 10
    assert suggested_offset_s(marker_s=100.0, robot_event_s=102.5) == 2.5


def test_bad_points_change_nothing():
    owner = UserFactory()
    run = run_round_the_rail(owner, seconds=5.0)
    t0_s = run.start_at.timestamp()
    good = read_file_points(f"t,rssi\n{t0_s},-50\n".encode(), "csv")
    measurement_add(run=run, by=owner, name="rssi", points=good)
    before = (MeasurementPoint.objects.count(), AuditEvent.objects.count())
    in_ms = read_file_points(f"t,rssi\n{t0_s * 1000},-50\n".encode(), "csv")
    twice = read_file_points(f"t,rssi\n{t0_s + 1},-50\n{t0_s + 1},-51\n".encode(), "csv")
    other_columns = read_file_points(f"t,noise\n{t0_s + 2},-90\n".encode(), "csv")
    refusals = [
        (in_ms, "rssi", {}, "more than 7 days from the run"),
        (twice, "rssi", {}, "rows 1 and 2 have the same time"),
        (other_columns, "rssi", {}, "has the columns rssi"),
        (good, "RSSI walk!", {}, "letters, digits"),
        (good, "rssi", {"clock_offset_s": 1e9}, "clock offset"),
    ]
    for points, name, extra, said in refusals:
        with pytest.raises(MeasurementRefused, match=said):
            measurement_add(run=run, by=owner, name=name, points=points, **extra)
    assert (MeasurementPoint.objects.count(), AuditEvent.objects.count()) == before
    assert MeasurementSeries.objects.get(run=run).clock_offset_s == 0.0


def test_a_point_in_a_gap_of_the_samples_is_marked_and_deleting_takes_every_point():
    owner = UserFactory()
    run = run_round_the_rail(owner, seconds=10.0)
    Sample.objects.filter(run=run, seq__in=range(40, 60)).delete()  # 3.9 s to 5.9 s lost
    t0_s = run.start_at.timestamp()
    text = f"t,rssi\n{t0_s + 1.05},-50\n{t0_s + 5.0},-51\n{t0_s - 3},-52\n{t0_s + 60},-53\n"
    added = measurement_add(
        run=run, by=owner, name="rssi", points=read_file_points(text.encode(), "csv")
    )
    assert added.series.summary["columns"]["rssi"]["where"] == {
        "placed": 1,
        "before": 1,
        "after": 1,
        "gap": 1,
    }
    measurement_delete(series=added.series, by=owner)
    assert not MeasurementSeries.objects.filter(run=run).exists()
    assert not MeasurementPoint.objects.exists()
    assert AuditEvent.objects.filter(action="measurement.delete").count() == 1


def test_a_marker_of_the_first_segments_start_offers_the_offset_that_aligns_the_clocks():
    owner = UserFactory()
    run = run_round_the_rail(owner, seconds=10.0)  # its first segment begins at its start
    t0_s = run.start_at.timestamp()
    # The measuring machine's clock is 2.5 s behind: it marked that start at t0 - 2.5.
    text = "t,rssi\n" + "".join(f"{t0_s - 2.5 + 0.5 * i:.6f},{-50 - i}\n" for i in range(20))
    added = measurement_add(
        run=run,
        by=owner,
        name="rssi",
        points=read_file_points(text.encode(), "csv"),
        marker_at=datetime.fromtimestamp(t0_s - 2.5, UTC),
    )
    summary = added.series.summary
    assert summary["suggested_offset_s"] == pytest.approx(2.5, abs=1e-6)
    assert summary["columns"]["rssi"]["where"]["before"] == 5
    aligned = measurement_update(
        series=added.series, by=owner, clock_offset_s=summary["suggested_offset_s"]
    )
    assert aligned.summary["columns"]["rssi"]["where"] == {
        "placed": 20,
        "before": 0,
        "after": 0,
        "gap": 0,
    }
    with pytest.raises(MeasurementRefused, match="marker"):
        measurement_update(
            series=aligned, by=owner, marker_at=datetime.fromtimestamp(t0_s + 9e6, UTC)
        )


def test_each_change_of_a_series_is_one_event_of_the_runs_owner_and_the_same_points_none():
    owner = UserFactory()
    run = run_round_the_rail(owner, seconds=5.0)
    t0_s = run.start_at.timestamp()
    text = "t,rssi\n" + "".join(f"{t0_s + i * 0.5},{-50 - i}\n" for i in range(6))
    points = read_file_points(text.encode(), "csv")
    added = measurement_add(run=run, by=owner, name="rssi", points=points, via="api")
    measurement_add(run=run, by=owner, name="rssi", points=points, via="api")  # nothing new
    with pytest.raises(MeasurementRefused):
        measurement_add(run=run, by=owner, name="rssi", points=points, clock_offset_s=1e9)
    measurement_update(series=added.series, by=owner, clock_offset_s=0.25, via="web")
    measurement_delete(series=added.series, by=owner, via="cli")
    events_sequence()
    events = list(Event.objects.filter(type="run.measured").order_by("position"))
    for event in events:
        jsonschema.validate(event.payload, EVENT_TYPES["run.measured"].payload)
        assert event.owner_id == owner.pk
        assert event.subject == f"run:{run.pk}"
    assert [
        (e.payload["change"], e.payload["points"], e.payload["stored"], e.payload["via"])
        for e in events
    ] == [("added", 6, 6, "api"), ("placed", 6, 0, "web"), ("deleted", 0, 0, "cli")]
    assert events[0].payload["reservation"] == run.reservation_id
    assert events[0].payload["resource"] == run.resource.name
