"""Campaigns: a sweep's runs queued all at once or not at all, served in fair-share order
with other people's, paused, resumed and cancelled. Every clock here is fixed (``now=``)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from bookings.choices import ReservationState
from core.errors import InvalidInput
from portal.experiments.models import Experiment
from portal.queue.allocation import queue_allocate
from portal.queue.campaigns import (
    campaign_cancel,
    campaign_create,
    campaign_pause,
    campaign_progress,
    campaign_resume,
)
from portal.queue.models import Campaign, QueueRequest, RequestState
from portal.queue.sweep import sweep_parse

pytestmark = pytest.mark.django_db

NOW = datetime(2030, 1, 7, 9, 0, tzinfo=UTC)
JSON = {"HTTP_ACCEPT": "application/json"}


def _spec(**changes):
    spec = {
        "title": "velocity sweep",
        "robot": "mobile-1",
        "parameters": {"velocity_mps": [0.5, 1.0], "direction": ["cw", "ccw"], "duration_s": 5},
        "repeats": 2,
        "earliest_at": "2030-01-07T09:00:00Z",
        "latest_end_at": "2030-01-09T09:00:00Z",
    }
    spec.update(changes)
    return spec


def _parse(spec):
    return sweep_parse(spec, parse_time=lambda _field, value: datetime.fromisoformat(value))


def test_a_sweep_expands_to_every_combination_each_repeat_in_order():
    runs = _parse(_spec()).runs()
    assert [(r.velocity_mps, r.direction, r.duration_s, r.repeat) for r in runs] == [
        (v, d, 5.0, repeat) for repeat in (1, 2) for v in (0.5, 1.0) for d in ("cw", "ccw")
    ]
    shuffled = _parse(_spec(order="random", seed=7)).runs()
    assert sorted(shuffled, key=repr) == sorted(runs, key=repr)
    assert shuffled == _parse(_spec(order="random", seed=7)).runs()  # the seed decides
    ranged = _parse(
        _spec(parameters={"velocity_mps": {"from": 0.5, "to": 2.0, "step": 0.5},
                          "direction": "cw", "duration_s": [3, 4]})
    )  # fmt: skip
    assert ranged.velocities_mps == (0.5, 1.0, 1.5, 2.0)
    assert len(ranged.runs()) == 4 * 2 * 2


def test_a_campaign_queues_each_run_with_its_program_and_parameters(owner, mobile):
    campaign = campaign_create(owner=owner, spec=_spec())
    requests = list(campaign.requests.order_by("submitted_at", "pk"))
    assert len(requests) == 8
    first = requests[0]
    assert first.parameters == {
        "velocity_mps": 0.5,
        "direction": "cw",
        "duration_s": 5.0,
        "repeat": 1,
    }
    assert first.experiment.segments == [
        {"velocity_mps": 0.5, "direction": "cw", "duration_s": 5.0}
    ]
    assert first.earliest_at == NOW
    assert campaign_progress(campaign) == {"runs": 8, "queue": {"waiting": 8}, "run_states": {}}


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"parameters": {"velocity_mps": 1, "direction": "cw", "duration_s": 5, "gain": 3}},
         "parameters", "Unknown parameter(s): gain"),
        ({"colour": "red"}, "colour", "Unknown field(s): colour"),
        ({"parameters": {"velocity_mps": [0.1 * i for i in range(10)],
                         "direction": ["cw", "ccw"], "duration_s": list(range(1, 11))},
          "repeats": 50}, "parameters", "would queue 10000 runs; at most 200"),
        ({"parameters": {"velocity_mps": [0.5, 3.0], "direction": "cw", "duration_s": 5}},
         "velocity_mps", "3"),
        ({"parameters": {"velocity_mps": 1, "direction": "up", "duration_s": 5}},
         "direction", "one of"),
        ({"robot": "node-01"}, "robot", "not a robot"),
        ({"latest_end_at": "2030-01-07T09:00:04Z"}, "latest_end_at", "no room"),
        ({"latest_end_at": "tomorrow"}, "latest_end_at", "offset"),
    ],
)  # fmt: skip
def test_a_bad_campaign_file_is_refused_with_its_field_and_nothing_is_queued(
    owner, mobile, change, field, words
):
    with pytest.raises(InvalidInput) as refused:
        campaign_create(owner=owner, spec=_spec(**change))
    assert field in refused.value.fields, refused.value.fields
    assert words in refused.value.message
    assert not Campaign.objects.exists()
    assert not QueueRequest.objects.exists()
    assert not Experiment.objects.exists()


def test_two_campaigns_at_once_are_served_in_fair_share_order(owner, other, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    mine = campaign_create(owner=owner, spec=_spec(repeats=1))
    theirs = campaign_create(owner=other, spec=_spec(repeats=1))
    queue_allocate(now=NOW)
    booked = sorted(
        QueueRequest.objects.filter(state=RequestState.BOOKED).select_related("reservation"),
        key=lambda r: r.reservation.start_at,
    )
    assert len(booked) == 8
    # The rule, computed here: each next slot to whoever has the least booked robot time,
    # then to who asked first; each person's runs in the order they were listed.
    used = {owner.pk: 0.0, other.pk: 0.0}
    waiting = {c.owner_id: list(c.requests.order_by("submitted_at", "pk")) for c in (mine, theirs)}
    expected = []
    while any(waiting.values()):
        who = min(
            (o for o in waiting if waiting[o]),
            key=lambda o: (used[o], waiting[o][0].submitted_at, waiting[o][0].pk),
        )
        request = waiting[who].pop(0)
        expected.append(request.pk)
        used[who] += request.duration_s
    assert [r.pk for r in booked] == expected
    assert {r.reservation.owner_id for r in booked[:2]} == {owner.pk, other.pk}


def test_a_paused_campaign_is_passed_over_until_resumed(owner, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    campaign = campaign_create(owner=owner, spec=_spec(repeats=1))
    campaign_pause(campaign=campaign, by=owner)
    assert queue_allocate(now=NOW).booked == []
    campaign_resume(campaign=campaign, by=owner)
    assert len(queue_allocate(now=NOW).booked) == 4


def test_cancelling_withdraws_the_waiting_and_keeps_or_cancels_the_booked(owner, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    settings.QUEUE_HORIZON_S = 120  # two runs of a minute fit before it, two wait
    kept = campaign_create(owner=owner, spec=_spec(repeats=1))
    assert len(queue_allocate(now=NOW).booked) == 2
    campaign_cancel(campaign=kept, by=owner, cancel_booked=False, reason="enough")
    states = sorted(r.state for r in kept.requests.all())
    assert states == ["booked", "booked", "cancelled", "cancelled"]
    for request in kept.requests.filter(state=RequestState.BOOKED):
        assert request.reservation.state == ReservationState.CONFIRMED

    dropped = campaign_create(owner=owner, spec=_spec(repeats=1, title="second"))
    later = NOW + timedelta(hours=1)
    assert len(queue_allocate(now=later).booked) == 2
    campaign_cancel(campaign=dropped, by=owner, cancel_booked=True)
    for request in dropped.requests.select_related("reservation"):
        if request.reservation is not None:
            assert request.reservation.state == ReservationState.CANCELLED
        else:
            assert request.state == RequestState.CANCELLED


def test_through_the_api_a_campaign_is_made_listed_and_refused_when_bad(
    api, client_for, other, mobile
):
    made = api.post("/api/v1/campaigns/", _spec(), format="json")
    assert made.status_code == 201, made.content
    body = made.json()
    assert body["progress"]["runs"] == 8
    assert body["runs"][0]["parameters"]["velocity_mps"] == 0.5
    shown = api.get(f"/api/v1/campaigns/{body['id']}/", **JSON).json()
    assert [r["request"] for r in shown["runs"]] == [r["request"] for r in body["runs"]]
    assert client_for(other).get(f"/api/v1/campaigns/{body['id']}/", **JSON).status_code == 404
    bad = api.post("/api/v1/campaigns/", _spec(repeats=500), format="json")
    assert bad.status_code == 400
    assert Campaign.objects.count() == 1
