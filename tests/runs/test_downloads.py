"""Downloads written by the database: exact values, awkward text, gzip when accepted; and the
run report's cache, which never mixes two databases."""

from __future__ import annotations

import csv
import gzip
import io
import json
from datetime import UTC, datetime, timedelta

import pytest
from django.core.cache import cache
from django.db import connection
from django.utils import timezone

from basestation.contract import SAMPLE_COLUMNS, SAMPLE_FIELDS
from portal.runs.downloads import accepts_gzip
from portal.runs.models import Run
from portal.runs.selectors import run_report
from portal.runs.services.collection import samples_ingest
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState

pytestmark = pytest.mark.django_db

# Whole seconds and trailing zeros: the database's own text drops them, the download may not.
T0 = datetime(2026, 11, 25, 10, 0, 0, tzinfo=UTC).timestamp()
TIMES = [T0, T0 + 0.5, T0 + 0.123456, T0 + 1.000001]
AWKWARD = ['a"b', "c\\d", "e,f", "g\nh", "ü\tß", None]


def _samples() -> list[dict]:
    return [
        {"seq": i + 1, "t": t, "segment": 0 if i % 2 else None, "commanded_velocity_mps": 1.0,
         "velocity_mps": 0.1 * i, "direction": "ccw" if i % 2 else "cw", "battery_v": 60.0,
         "track_m": 1e-7 * i, "fix_quality": None, "lat_deg": 40.6343, "lon_deg": None,
         "grid_id": AWKWARD[i % len(AWKWARD)], "lap": -i}
        for i, t in enumerate(TIMES * 3)
    ]  # fmt: skip


@pytest.fixture
def run(owner, mobile, experiment):
    start = timezone.now() + timedelta(hours=1)
    reservation = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=start + timedelta(minutes=5),
        experiment=experiment,
    )  # fmt: skip
    samples_ingest(run=reservation.run, samples=_samples())
    return reservation.run


def _iso(epoch_s: float) -> str:
    return datetime.fromtimestamp(epoch_s, UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _expected() -> list[dict]:
    return [{**s, "t": _iso(s["t"])} for s in _samples()]


def _body(response) -> bytes:
    body = b"".join(response.streaming_content)
    return gzip.decompress(body) if response.get("Content-Encoding") == "gzip" else body


def test_the_json_download_holds_every_value_exactly(run, client):
    client.force_login(run.reservation.owner)
    document = json.loads(_body(client.get(f"/api/v1/runs/{run.pk}/samples.json")))
    assert document["samples"] == _expected()
    assert [list(s) for s in document["samples"]] == [list(SAMPLE_FIELDS)] * len(_samples())


def test_the_json_download_is_whole_across_chunks_and_for_a_run_without_samples(
    run, client, monkeypatch, owner, mobile, experiment
):
    client.force_login(owner)
    # A chunk of about one row: every object's pieces meet across chunk borders.
    monkeypatch.setattr("portal.runs.queries.CHUNK_BYTES", 100)
    document = json.loads(_body(client.get(f"/api/v1/runs/{run.pk}/samples.json")))
    assert document["samples"] == _expected()

    start = timezone.now() + timedelta(hours=2)
    empty = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=start + timedelta(minutes=5),
        experiment=experiment,
    ).run  # fmt: skip
    document = json.loads(_body(client.get(f"/api/v1/runs/{empty.pk}/samples.json")))
    assert document["samples"] == []
    assert document["run"] == empty.pk


def test_the_csv_download_holds_every_value_exactly(run, client):
    client.force_login(run.reservation.owner)
    text = _body(client.get(f"/api/v1/runs/{run.pk}/samples.csv")).decode()
    rows = list(csv.reader(io.StringIO(text, newline="")))
    assert rows[0] == list(SAMPLE_FIELDS)
    # Numbers as the database writes them (1 for 1.0): compared as numbers.
    kinds = [c.kind for c in SAMPLE_COLUMNS]
    read = [
        [
            None if v == "" else float(v) if k in ("int", "float") else v
            for v, k in zip(row, kinds, strict=True)
        ]
        for row in rows[1:]
    ]
    assert read == [list(s.values()) for s in _expected()]


@pytest.mark.parametrize("path", ["samples.csv", "samples.json"])
def test_a_download_is_gzipped_when_the_client_accepts_it(run, client, path):
    client.force_login(run.reservation.owner)
    for url in (f"/runs/{run.pk}/{path}", f"/api/v1/runs/{run.pk}/{path}"):
        plain = client.get(url, HTTP_ACCEPT_ENCODING="identity")
        packed = client.get(url, HTTP_ACCEPT_ENCODING="gzip, deflate, br")
        assert plain.get("Content-Encoding") is None
        assert packed["Content-Encoding"] == "gzip"
        assert "Accept-Encoding" in packed["Vary"]
        assert "Accept-Encoding" in plain["Vary"]
        assert gzip.decompress(b"".join(packed.streaming_content)) == b"".join(
            plain.streaming_content
        )


@pytest.mark.parametrize(
    ("header", "accepted"),
    [
        ("gzip", True),
        ("deflate, gzip;q=0.5", True),
        ("*", True),
        ("GZIP ; Q=1", True),
        ("gzip;q=0", False),
        ("gzip;q=0.0, identity", False),
        ("br, deflate", False),
        ("", False),
        ("gzip;q=abc", False),
    ],
)
def test_accept_encoding_is_read_with_its_weights(header, accepted):
    assert accepts_gzip(header) is accepted


def test_a_cached_report_of_another_database_is_never_served(run):
    """Run ids repeat between databases that share a cache (a test's, a benchmark's)."""
    Run.objects.filter(pk=run.pk).update(state=RunState.COMPLETED)
    run.refresh_from_db()  # final: cached by the run's identity alone, not its sample count
    cache.clear()
    name = connection.settings_dict["NAME"]
    try:
        # The same run id and identity on "another" database, with other samples.
        connection.settings_dict["NAME"] = f"{name}_elsewhere"
        run.samples.filter(seq__gt=1).delete()
        assert run_report(run=run).analysis.samples == 1
    finally:
        connection.settings_dict["NAME"] = name
    samples_ingest(run=run, samples=_samples())
    run.refresh_from_db()
    assert run_report(run=run).analysis.samples == len(_samples())


def test_uncached_computes_afresh_and_stores_nothing(run):
    run_report(run=run, cached=False)
    run.samples.filter(seq__gt=1).delete()
    assert run_report(run=run, cached=False).analysis.samples == 1
