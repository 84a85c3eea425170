"""Sample pages from the agent are stored once, however often or overlapping they arrive."""

from __future__ import annotations

import json
import time
from datetime import timedelta

import pytest
import redis
from django.utils import timezone

from core import live
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
        collection, "samples_publish_on_commit", lambda run_id, event: events.append(dict(event))
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


@pytest.fixture
def run_channel_events(run, settings):
    """What the run's channel on the real Redis bus carries from now on."""
    client = redis.Redis.from_url(settings.REDIS_URL)
    client.delete(live.announced_key(run.pk))
    pubsub = client.pubsub()
    pubsub.subscribe(live.REDIS_PREFIX + live.run_channel(run.pk))

    def events(expected: int) -> list[tuple[int, int]]:
        """The next ``expected`` events' ranges, then whatever else comes within half a
        second (to show there is nothing more)."""
        heard: list[tuple[int, int]] = []
        deadline = time.monotonic() + 10
        quiet_until = None
        while time.monotonic() < (quiet_until or deadline):
            message = pubsub.get_message(ignore_subscribe_messages=True, timeout=0.1)
            if message is not None:
                event = json.loads(message["data"])
                heard.append((event["first_seq"], event["last_seq"]))
            if len(heard) >= expected and quiet_until is None:
                quiet_until = time.monotonic() + 0.5
        return heard

    yield events
    pubsub.close()
    client.close()


def test_samples_stored_and_never_announced_are_announced_once_when_taken_up(
    run, run_channel_events, monkeypatch, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks(execute=True):
        samples_ingest(run=run, samples=_page(1, 10))
    # A publisher killed between its commit and its announcement: 11 to 20 stored, not announced.
    with django_capture_on_commit_callbacks(execute=False):
        samples_ingest(run=run, samples=_page(11, 20))
    with django_capture_on_commit_callbacks(execute=True):
        samples_ingest(run=run, samples=_page(21, 25))
    assert run_channel_events(2) == [(1, 10), (21, 25)]

    assert collection.samples_announce_missed(run=run) == 10
    assert run_channel_events(1) == [(11, 20)]
    # Taken up again: every stored sample has been announced, nothing is said twice.
    assert collection.samples_announce_missed(run=run) == 0
    assert run_channel_events(0) == []


def test_without_marks_on_the_bus_nothing_is_announced_again(run, settings, tmp_path):
    settings.REDIS_URL = ""  # the file transport (make run without Redis) keeps no marks
    settings.LIVE_DIR = tmp_path / "live"
    samples_ingest(run=run, samples=_page(1, 10))
    assert collection.samples_announce_missed(run=run) == 0


def test_marks_refused_by_redis_still_announce_the_samples(run, run_channel_events, monkeypatch):
    def refuse(self, channel, payload, key, seqs):
        raise redis.ResponseError("ERR unknown command 'BITFIELD'")

    monkeypatch.setattr(live.RedisBus, "publish_marked", refuse)
    assert live.samples_publish(run.pk, {"type": "samples", "first_seq": 1, "last_seq": 5})
    assert run_channel_events(1) == [(1, 5)]
