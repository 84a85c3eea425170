"""Sample pages from the agent are stored once, however often or overlapping they arrive."""

from __future__ import annotations

import json
import time
from datetime import UTC, datetime, timedelta

import pytest
import redis
from django.db import connection
from django.utils import timezone
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from basestation.contract import SAMPLE_COLUMNS, SAMPLE_FIELDS
from core import live
from portal.runs.models import Sample
from portal.runs.services import collection
from portal.runs.services.collection import samples_ingest
from portal.runs.services.reservations import reservation_create

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
    reservation = reservation_create(
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

    def publish(run_id: int, created_at: object, first_seq: int, times_s: list[float]) -> None:
        events.append(live.samples_event(first_seq, first_seq + len(times_s) - 1, times_s[-1]))

    monkeypatch.setattr(collection, "samples_publish_on_commit", publish)
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
    client.delete(live.announced_key(run.pk, run.created_at))
    pubsub = client.pubsub()
    pubsub.subscribe(live.redis_channel(live.run_channel(run.pk)))

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


def test_an_announcement_late_behind_the_collectors_catching_up_repeats_nothing(
    run, run_channel_events, django_capture_on_commit_callbacks
):
    # A sweep stored 1 to 20; its announcement is still on its way (after its commit) when
    # the restarted collector takes the run up, finds them unmarked and announces them.
    with django_capture_on_commit_callbacks(execute=False) as late:
        samples_ingest(run=run, samples=_page(1, 20))
    assert collection.samples_announce_missed(run=run) == 20
    with django_capture_on_commit_callbacks(execute=False) as later:
        samples_ingest(run=run, samples=_page(15, 30))  # 21 to 30 new
    for announce in [*late, *later]:
        announce()
    assert run_channel_events(2) == [(1, 20), (21, 30)]


def test_marks_left_by_an_earlier_run_of_the_same_id_claim_nothing(
    run, run_channel_events, django_capture_on_commit_callbacks, settings
):
    # A database made again, or restored from a backup: a run of this id made the day before
    # left its marks on Redis, which outlive it by a week.
    earlier = run.created_at - timedelta(days=1)
    assert live.samples_publish(run.pk, earlier, 1, [time.time()] * 10)
    assert run_channel_events(1) == [(1, 10)]
    with django_capture_on_commit_callbacks(execute=True):
        samples_ingest(run=run, samples=_page(1, 10))
    assert run_channel_events(1) == [(1, 10)]
    redis.Redis.from_url(settings.REDIS_URL).delete(live.announced_key(run.pk, earlier))


def test_without_marks_on_the_bus_nothing_is_announced_again(run, settings, tmp_path):
    settings.REDIS_URL = ""  # the file transport (make run without Redis) keeps no marks
    settings.LIVE_DIR = tmp_path / "live"
    samples_ingest(run=run, samples=_page(1, 10))
    assert collection.samples_announce_missed(run=run) == 0


def test_marks_refused_by_redis_still_announce_the_samples(run, run_channel_events, monkeypatch):
    def refuse(self, channel, key, first_seq, times_s):
        raise redis.ResponseError("NOSCRIPT scripting is disabled")

    monkeypatch.setattr(live.RedisBus, "publish_samples", refuse)
    assert live.samples_publish(run.pk, run.created_at, 1, [time.time()] * 5)
    assert run_channel_events(1) == [(1, 5)]


_FLOATS = st.floats(allow_nan=False, allow_infinity=False, width=64)
_TEXT = st.text(
    alphabet=st.characters(blacklist_characters="\x00", blacklist_categories=["Cs"]), max_size=8
)


def _sample(seq: int, values: tuple) -> dict:
    t, velocity, track, lat, grid = values
    return {
        "seq": seq, "t": t, "segment": None if seq % 3 else seq, "commanded_velocity_mps": -track,
        "velocity_mps": velocity, "direction": "ccw" if seq % 2 else "cw", "battery_v": track,
        "track_m": track, "fix_quality": None if seq % 2 else 4, "lat_deg": lat,
        "lon_deg": None, "grid_id": grid, "lap": -seq,
    }  # fmt: skip


_PAGES = st.lists(
    st.tuples(
        st.floats(min_value=0, max_value=4_000_000_000, allow_nan=False),
        st.floats(min_value=0, allow_nan=False, allow_infinity=False),
        _FLOATS,
        st.none() | _FLOATS,
        st.none() | _TEXT,
    ),
    min_size=1,
    max_size=40,
)


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(pages=st.lists(_PAGES, min_size=1, max_size=3))
def test_every_value_is_stored_as_the_agent_sent_it(run, pages):
    """What the database holds is what the contract reads from the agent's JSON, value for
    value (floats to the bit, times to the microsecond, any text), new page or merged."""
    Sample.objects.filter(run=run).delete()
    sent: dict[int, dict] = {}
    for page in pages:
        # Each page starts inside the one before it: the second and later are merged.
        first = max(1, len(sent) - 2)
        samples = [_sample(first + i, values) for i, values in enumerate(page)]
        samples_ingest(run=run, samples=samples)
        for sample in samples:
            sent.setdefault(sample["seq"], sample)
    stored = {row["seq"]: row for row in Sample.objects.filter(run=run).values(*SAMPLE_FIELDS)}
    assert stored.keys() == sent.keys()
    for seq, sample in sent.items():
        row = stored[seq]
        expected_t = datetime.fromtimestamp(sample["t"], tz=UTC)
        assert row["t"] == expected_t, seq
        for field in SAMPLE_FIELDS:
            if field != "t":
                assert row[field] == sample[field], (seq, field, row[field], sample[field])


def test_text_no_database_can_hold_is_refused_and_nothing_is_stored(run):
    page = _page(1, 3)
    page[1]["grid_id"] = "A\x001"
    with pytest.raises(ValueError, match="grid_id: holds a NUL character or a lone surrogate"):
        samples_ingest(run=run, samples=page)
    page[1]["grid_id"] = "A\ud8001"
    with pytest.raises(ValueError, match="grid_id: holds a NUL character or a lone surrogate"):
        samples_ingest(run=run, samples=page)
    assert not Sample.objects.filter(run=run).exists()


@pytest.mark.parametrize(
    ("field", "value"),
    [("segment", 40_000), ("fix_quality", -1), ("seq", 2**31), ("lap", -(2**31))],
)
def test_an_integer_its_column_cannot_store_is_refused_not_wrapped(run, field, value):
    page = _page(1, 3)
    page[1][field] = value
    with pytest.raises(ValueError, match=f"{field}: {value}"):
        samples_ingest(run=run, samples=page)
    assert not Sample.objects.filter(run=run).exists()


def test_the_contracts_integer_bounds_fit_the_portals_columns():
    for column in SAMPLE_COLUMNS:
        if column.kind != "int":
            continue
        field = Sample._meta.get_field(column.name)
        low, high = connection.ops.integer_field_range(field.get_internal_type())
        assert column.minimum is not None, column.name
        assert column.maximum is not None, column.name
        assert low <= column.minimum, column.name
        assert column.maximum <= high, column.name
