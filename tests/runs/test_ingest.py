"""Sample pages from the agent are stored once, however often or overlapping they arrive."""

from __future__ import annotations

import time
from datetime import timedelta

import pytest
from django.utils import timezone

from portal.runs.models import Sample
from portal.runs.services import collection
from portal.runs.services.booking import booking_create
from portal.runs.services.collection import samples_ingest

pytestmark = pytest.mark.django_db


def _page(first: int, last: int) -> list[dict]:
    t0 = time.time()
    return [
        {"seq": i, "t": t0 + i / 20, "segment": 0, "commanded_velocity_mps": 0.5,
         "velocity_mps": 0.49, "direction": "cw", "battery_v": 60.1, "track_m": i / 40,
         "fix_quality": 4, "lat_deg": 40.6343, "lon_deg": -8.6601, "grid_id": "B2", "lap": i // 50}
        for i in range(first, last + 1)
    ]  # fmt: skip


@pytest.fixture
def run(owner, mobile, experiment):
    start = timezone.now() + timedelta(hours=1)
    reservation = booking_create(
        owner=owner, resource=mobile, start_at=start, end_at=start + timedelta(minutes=5),
        experiment=experiment,
    )  # fmt: skip
    return reservation.run


def test_a_repeated_page_is_stored_once(run):
    samples_ingest(run=run, samples=_page(1, 100))
    samples_ingest(run=run, samples=_page(1, 100))
    assert Sample.objects.filter(run=run).count() == 100


def test_an_overlapping_page_adds_only_what_is_new(run):
    samples_ingest(run=run, samples=_page(1, 100))
    samples_ingest(run=run, samples=_page(51, 150))
    seqs = list(Sample.objects.filter(run=run).order_by("seq").values_list("seq", flat=True))
    assert seqs == list(range(1, 151))
    run.refresh_from_db()
    assert run.last_seq == 150


def test_a_page_stored_meanwhile_by_another_collection_is_merged(run, monkeypatch):
    """The overlap check and the COPY are not atomic: a duplicate found by the COPY itself
    still ends in the merge."""
    samples_ingest(run=run, samples=_page(1, 100))
    monkeypatch.setattr(collection, "_overlaps_stored", lambda run_id, rows: False)
    samples_ingest(run=run, samples=_page(51, 150))
    seqs = list(Sample.objects.filter(run=run).order_by("seq").values_list("seq", flat=True))
    assert seqs == list(range(1, 151))


def test_a_page_out_of_order_still_moves_last_seq_forward_only(run):
    samples_ingest(run=run, samples=_page(101, 200))
    samples_ingest(run=run, samples=_page(1, 100))
    run.refresh_from_db()
    assert run.last_seq == 200
    assert Sample.objects.filter(run=run).count() == 200


def test_the_position_comes_through_to_the_csv(run, client):
    samples_ingest(run=run, samples=_page(1, 60))
    client.force_login(run.reservation.owner)
    response = client.get(f"/api/v1/runs/{run.pk}/samples.csv")
    rows = b"".join(response.streaming_content).decode().splitlines()
    assert rows[0].endswith("track_m,fix_quality,lat_deg,lon_deg,grid_id,lap")
    assert rows[-1].endswith(",4,40.6343,-8.6601,B2,1")
    page = client.get(f"/api/v1/runs/{run.pk}/samples/", {"limit": 1}).json()
    assert page["samples"][0]["grid_id"] == "B2"


def test_the_sample_columns_are_every_field_of_a_sample():
    from portal.runs.models import SAMPLE_FIELDS

    stored = [f.name for f in Sample._meta.concrete_fields if f.name not in ("id", "run")]
    assert list(SAMPLE_FIELDS) == stored


@pytest.fixture
def announced(monkeypatch) -> list[dict]:
    """The live events ``samples_ingest`` publishes (once committed)."""
    events: list[dict] = []
    monkeypatch.setattr(
        collection, "publish_on_commit", lambda channel, event: events.append(dict(event))
    )
    return events


def test_each_sample_is_announced_once_however_pages_overlap(run, announced):
    assert samples_ingest(run=run, samples=_page(1, 100)) == 100
    assert samples_ingest(run=run, samples=_page(51, 150)) == 50
    assert samples_ingest(run=run, samples=_page(1, 150)) == 0
    assert [(e["first_seq"], e["last_seq"], e["count"]) for e in announced] == [
        (1, 100, 100),
        (101, 150, 50),
    ]
    assert announced[-1]["last_t"] == pytest.approx(time.time() + 150 / 20, abs=5)


def test_new_samples_around_stored_ones_are_announced_as_their_own_ranges(run, announced):
    samples_ingest(run=run, samples=_page(11, 20))
    samples_ingest(run=run, samples=_page(1, 30))
    assert [(e["first_seq"], e["last_seq"]) for e in announced] == [(11, 20), (1, 10), (21, 30)]
