"""The run page's analysis and downloads on SQLite, where time is read another way."""

from __future__ import annotations

import csv
import io
import json
from datetime import datetime

import pytest

from tests.sqlite import run_on_sqlite

SCRIPT = r"""
import json
from datetime import timedelta
from django.utils import timezone
from bookings.models import Resource
from portal.runs.services.reservations import reservation_create
from core.accounts.models import User
from portal.experiments.models import Experiment
from portal.runs.models import Run
from portal.runs.selectors import (
    run_report, run_report_json, run_samples_csv, run_samples_json,
)
from portal.runs.services.collection import samples_ingest
from tests.runs.driving import RAIL_M, drive, segments

program = [(2.0, "cw", 60.0), (1.0, "ccw", 60.0)]
alice = User.objects.create_user("alice")
robot = Resource.objects.create(name="mobile-1", kind="mobile", agent_url="http://127.0.0.1:1",
                                max_velocity_mps=2.0, max_accel_mps2=1.0)
experiment = Experiment.objects.create(owner=alice, title="there and back",
                                       segments=segments(program))
start = timezone.now() + timedelta(hours=1)
reservation = reservation_create(owner=alice, resource=robot, start_at=start,
                                 end_at=start + timedelta(minutes=3), experiment=experiment)
run = reservation.run
samples = [{**{k: v for k, v in r._asdict().items() if k != "t_s"},
            "t": start.timestamp() + r.t_s, "lat_deg": None, "lon_deg": None,
            "grid_id": None, "lap": None} for r in drive(program)]
samples_ingest(run=run, samples=samples)
Run.objects.filter(pk=run.pk).update(rail_length_m=RAIL_M)
run.refresh_from_db()
print("report:", json.dumps(run_report_json(run_report(run=run, pass_at_m=20.0))))
print("json:", b"".join(run_samples_json(run=run)).decode())
print("csv:", json.dumps(b"".join(run_samples_csv(run=run)).decode()))
"""


def _line(lines: list[str], prefix: str) -> str:
    return next(line for line in lines if line.startswith(prefix))[len(prefix) :]


def test_the_run_analysis_and_downloads_work_on_sqlite(tmp_path):
    lines = run_on_sqlite(SCRIPT, tmp_path)
    report = json.loads(_line(lines, "report:"))
    assert report["samples"] == 2400
    # Out from 10 m to 130 m at 2 m/s and back to 70 m at 1 m/s: 20 m and 120 m are passed
    # at 5 s and 55 s going clockwise, 120 m again at 70 s coming back.
    assert [(p["direction"], p["t_s"]) for p in report["passes"]] == [
        ("cw", 5.0),
        ("cw", 55.0),
        ("ccw", 70.0),
    ]
    # A lap is a rail's length of path from where the run began: 100 m at 2 m/s.
    assert [lap["end_s"] for lap in report["laps"]] == [50.0]
    document = json.loads(_line(lines, "json:"))
    assert len(document["samples"]) == 2400
    first, second = (datetime.fromisoformat(s["t"]) for s in document["samples"][:2])
    assert document["samples"][0]["t"].endswith("Z")
    assert (second - first).total_seconds() == pytest.approx(0.05, abs=1e-6)
    # The CSV says what the JSON says, column by column (read by name, as the header gives).
    rows = list(csv.DictReader(io.StringIO(json.loads(_line(lines, "csv:")))))
    assert len(rows) == 2400
    for row, sample in zip(rows, document["samples"], strict=True):
        assert row == {k: "" if v is None else str(v) for k, v in sample.items()}
