"""A run's measurement series in its downloads: a resource of the run package per series
(valid by Frictionless, its foreign key to the samples checked), and Parquet files of the
samples and of each series that pandas reads with the types ``docs/run-package.md`` states."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import zipfile

import pandas as pd
import pytest
from frictionless import validate

from basestation.contract import SAMPLE_FIELDS
from portal.runs.measurements import measurement_add, read_file_points
from portal.runs.models import Sample
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db

ROBOT_COLUMNS = [
    "robot_where", "robot_track_m", "robot_unwrapped_m", "robot_lap", "robot_segment",
    "robot_commanded_velocity_mps", "robot_velocity_mps", "robot_lat_deg", "robot_lon_deg",
    "robot_grid_id", "robot_sample_seq",
]  # fmt: skip


@pytest.fixture
def run(owner, mobile):
    run = completed_run(owner, mobile, [(0.5, "cw", 2.0), (0.25, "ccw", 1.0)])
    t0_s = run.start_at.timestamp()
    # Two columns on their own times (rssi every 0.2 s, snr every 0.5 s), one point before
    # the run's first sample.
    text = "t,rssi,snr\n" + "".join(
        f"{t0_s + 0.1 * i:.3f},{-50 - i % 7 if i % 2 == 0 else ''},{20 + i if i % 5 == 0 else ''}\n"
        for i in range(25)
    )
    text += f"{t0_s - 2:.3f},-40,\n"
    measurement_add(
        run=run, by=owner, name="rssi", unit="dBm", points=read_file_points(text.encode(), "csv")
    )
    return run


def test_the_package_holds_each_series_as_a_valid_resource_tied_to_the_samples(api, run, tmp_path):
    answer = api.get(f"/api/v1/runs/{run.pk}/package.zip")
    assert answer.status_code == 200
    zipfile.ZipFile(io.BytesIO(b"".join(answer.streaming_content))).extractall(tmp_path)
    report = validate(tmp_path / "datapackage.json")
    assert report.valid, report.flatten(["rowNumber", "fieldName", "type", "note"])
    with (tmp_path / "measurements" / "rssi.csv").open(newline="") as stream:
        table = list(csv.reader(stream))
    assert table[0] == ["t", "t_base", "rssi", "snr", *ROBOT_COLUMNS]
    # rssi's 13 times, snr's two of its own (0.5 s and 1.5 s), the early one
    assert len(table) == 1 + 13 + 2 + 1
    assert table[1][4] == "before"
    assert {row[4] for row in table[1:]} == {"before", "placed"}
    assert "measurements/<name>.csv" in (tmp_path / "README.md").read_text()
    # A sample's seq that the series names must exist: the foreign key is checked.
    seq = int(table[-1][-1])
    path = tmp_path / "measurements" / "rssi.csv"
    changed = path.read_bytes().replace(f",{seq}\n".encode(), f",{seq + 1000}\n".encode())
    assert changed != path.read_bytes()
    path.write_bytes(changed)
    # Its size and hash put right, so that only the reference is wrong.
    descriptor = json.loads((tmp_path / "datapackage.json").read_text())
    (resource,) = [r for r in descriptor["resources"] if r["path"] == "measurements/rssi.csv"]
    resource["bytes"] = len(changed)
    resource["hash"] = "sha256:" + hashlib.sha256(changed).hexdigest()
    (tmp_path / "datapackage.json").write_text(json.dumps(descriptor))
    broken = validate(tmp_path / "datapackage.json")
    assert "foreign-key" in {row[0] for row in broken.flatten(["type"])}


def test_the_parquet_downloads_read_back_typed_by_pandas(api, run):
    samples = api.get(f"/api/v1/runs/{run.pk}/samples.parquet")
    assert samples.status_code == 200
    assert samples["Content-Type"] == "application/vnd.apache.parquet"
    frame = pd.read_parquet(io.BytesIO(b"".join(samples.streaming_content)))
    assert list(frame.columns) == list(SAMPLE_FIELDS)
    assert str(frame["t"].dtype) == "datetime64[us, UTC]"
    assert str(frame["seq"].dtype) == "int64"
    assert str(frame["track_m"].dtype) == "float64"
    assert len(frame) == Sample.objects.filter(run=run).count()

    series = api.get(f"/api/v1/runs/{run.pk}/measurements/rssi/points.parquet")
    assert series.status_code == 200
    assert 'filename="amazing-run-' in series["Content-Disposition"]
    frame = pd.read_parquet(io.BytesIO(b"".join(series.streaming_content)))
    assert list(frame.columns) == ["t", "t_base", "rssi", "snr", *ROBOT_COLUMNS]
    assert str(frame["t"].dtype) == "datetime64[us, UTC]"
    assert str(frame["rssi"].dtype) == "float64"
    assert str(frame["robot_sample_seq"].dtype) in ("Int64", "float64")
    assert frame["robot_where"].tolist()[0] == "before"
    assert frame["snr"].notna().sum() == 5
    assert frame["rssi"].notna().sum() == 14


def test_another_users_parquet_is_not_found(client_for, other, run):
    theirs = client_for(other)
    assert theirs.get(f"/api/v1/runs/{run.pk}/samples.parquet").status_code == 404
    assert theirs.get(f"/api/v1/runs/{run.pk}/measurements/rssi/points.parquet").status_code == 404
