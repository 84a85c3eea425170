"""A researcher's lists (own reservations, own runs, quota) are answered from the cache until a
row they show changes, and never show one user's answer to another (``core.api.cached_json``)."""

from __future__ import annotations

import json
import time
from datetime import UTC, datetime, timedelta

import pytest
import time_machine
from django.contrib.auth.models import Group
from django.db import connection
from django.test.utils import CaptureQueriesContext
from django.utils import timezone

from bookings.models import QuotaPolicy
from portal.runs.models import Run
from portal.runs.services.collection import samples_ingest
from portal.runs.services.reservations import reservation_create
from portal.runs.services.transitions import run_transition
from portal.runs.states import Cause, RunState
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db

JSON = {"HTTP_ACCEPT": "application/json"}


def _book(owner, mobile, experiment, *, hours: int = 1):
    start = timezone.now().replace(microsecond=0) + timedelta(hours=hours)
    return reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=30),
        experiment=experiment,
    )


def _ids(answer) -> list[int]:
    return [row["id"] for row in answer.json()["results"]]


def test_own_reservations_show_a_booking_a_cancel_and_a_run_state_at_once(
    api, owner, mobile, experiment
):
    assert _ids(api.get("/api/v1/reservations/", **JSON)) == []
    first = _book(owner, mobile, experiment)
    assert _ids(api.get("/api/v1/reservations/", **JSON)) == [first.pk]

    run_transition(run_id=first.run.pk, to_state=RunState.STAGED, cause=Cause.DISPATCH)
    listed = api.get("/api/v1/reservations/", **JSON).json()["results"]
    assert listed[0]["run"] == {"id": first.run.pk, "state": "staged"}

    second = _book(owner, mobile, experiment, hours=3)
    assert _ids(api.get("/api/v1/reservations/", **JSON)) == [first.pk, second.pk]
    assert api.delete(f"/api/v1/reservations/{second.pk}/").status_code == 200
    listed = api.get("/api/v1/reservations/", **JSON).json()["results"]
    assert [row["state"] for row in listed] == ["confirmed", "cancelled"]


def test_one_users_list_is_never_anothers(client_for, owner, other, admin_user, mobile):
    mine = _book(owner, mobile, ExperimentFactory(owner=owner))
    theirs = _book(other, mobile, ExperimentFactory(owner=other), hours=3)
    # The same URL for each of them, one after the other.
    assert _ids(client_for(owner).get("/api/v1/reservations/", **JSON)) == [mine.pk]
    assert _ids(client_for(other).get("/api/v1/reservations/", **JSON)) == [theirs.pk]
    everyone = _ids(client_for(admin_user).get("/api/v1/reservations/", **JSON))
    assert everyone == [mine.pk, theirs.pk]
    runs = client_for(other).get("/api/v1/runs/", **JSON).json()["results"]
    assert [run["id"] for run in runs] == [theirs.run.pk]


def test_filters_and_pages_are_answers_of_their_own(api, owner, mobile, experiment):
    first = _book(owner, mobile, experiment)
    second = _book(owner, mobile, experiment, hours=3)
    assert _ids(api.get("/api/v1/reservations/?limit=1", **JSON)) == [first.pk]
    assert _ids(api.get("/api/v1/reservations/?limit=1&offset=1", **JSON)) == [second.pk]
    assert _ids(api.get(f"/api/v1/reservations/?resource={mobile.name}", **JSON)) == [
        first.pk,
        second.pk,
    ]
    assert _ids(api.get("/api/v1/reservations/?resource=elsewhere", **JSON)) == []


def test_an_invalid_query_is_refused_every_time_and_keeps_nothing(api):
    for _ in range(2):
        refused = api.get("/api/v1/runs/?state=flying", **JSON)
        assert refused.status_code == 400
        assert refused.json()["fields"]["state"]


def test_own_runs_show_new_samples_and_a_filled_gap(api, owner, mobile, experiment):
    run = _book(owner, mobile, experiment).run

    def count() -> int:
        return api.get("/api/v1/runs/", **JSON).json()["results"][0]["sample_count"]

    t0 = time.time()

    def page(seqs):
        return [
            {"seq": i, "t": t0 + i / 20, "segment": 0, "commanded_velocity_mps": 0.5,
             "velocity_mps": 0.49, "direction": "cw", "battery_v": 60.1, "track_m": i / 40,
             "fix_quality": 4, "lat_deg": 40.6343, "lon_deg": -8.6601, "grid_id": "B2",
             "lap": 0}
            for i in seqs
        ]  # fmt: skip

    assert count() == 0
    samples_ingest(run=run, samples=page([1, 2, 3, 10]))
    assert count() == 4
    # Below the last sequence number: the run's row does not change, the count does.
    samples_ingest(run=Run.objects.get(pk=run.pk), samples=page([4, 5]))
    assert count() == 6


# Sunday night in Lisbon (winter time, UTC+0): the booking "in an hour", 23:40 to 00:10, is
# 20 minutes in this week (Monday 1 to Monday 8 November) and the rest in the next.
@time_machine.travel(datetime(2027, 11, 7, 22, 40, tzinfo=UTC))
def test_quota_follows_policies_groups_and_bookings(api, owner, mobile, experiment, settings):
    settings.TIME_ZONE = "Europe/Lisbon"
    assert api.get("/api/v1/quota/", **JSON).json() == {"policies": []}
    staff = Group.objects.create(name="students")
    policy = QuotaPolicy.objects.create(
        name="students' week", group=staff, max_hours=2, period="week"
    )
    assert api.get("/api/v1/quota/", **JSON).json() == {"policies": []}, "not in the group yet"
    owner.groups.add(staff)
    (use,) = api.get("/api/v1/quota/", **JSON).json()["policies"]
    assert use["policy"] == "students' week"
    assert use["scope"] == "group students"
    assert use["used_hours"] == 0
    booked = _book(owner, mobile, experiment)
    (use,) = api.get("/api/v1/quota/", **JSON).json()["policies"]
    assert (booked.start_at, booked.end_at) == (
        datetime(2027, 11, 7, 23, 40, tzinfo=UTC),
        datetime(2027, 11, 8, 0, 10, tzinfo=UTC),
    )
    week = (datetime.fromisoformat(use["period_start"]), datetime.fromisoformat(use["period_end"]))
    assert week == (datetime(2027, 11, 1, tzinfo=UTC), datetime(2027, 11, 8, tzinfo=UTC))
    assert use["used_hours"] == 0.333, "the 20 minutes before midnight"
    staff.name = "masters"
    staff.save()
    (use,) = api.get("/api/v1/quota/", **JSON).json()["policies"]
    assert use["scope"] == "group masters"
    QuotaPolicy.objects.filter(pk=policy.pk).update(max_hours=5)
    (use,) = api.get("/api/v1/quota/", **JSON).json()["policies"]
    assert use["max_hours"] == 5
    owner.groups.remove(staff)
    assert api.get("/api/v1/quota/", **JSON).json() == {"policies": []}


def test_the_browsable_api_is_answered_afresh_and_json_stays_cached(api, owner, mobile, experiment):
    _book(owner, mobile, experiment)
    page = api.get("/api/v1/reservations/", HTTP_ACCEPT="text/html")
    assert page.status_code == 200
    assert page["Content-Type"].startswith("text/html")
    answer = api.get("/api/v1/reservations/", **JSON)
    assert answer["Content-Type"] == "application/json"
    assert answer.json()["count"] == 1


@pytest.mark.django_db(transaction=True)
def test_the_runs_list_follows_its_runs_and_not_the_owners_other_bookings(
    api, owner, mobile, experiment
):
    """The runs list is kept under the runs' generation and the setup's, not its owner's
    bookings: a move or a cancel writes the run itself, and a booking of a fixed node leaves
    the list in the cache (committed changes: the cache is really read here)."""
    from bookings.models import CALENDAR_SETUP
    from bookings.services import reservation_create as book_nodes
    from portal.runs.models import RUNS
    from portal.runs.services.reservations import reservation_cancel, reservation_reschedule
    from tests.factories import FixedResourceFactory

    node = FixedResourceFactory()  # the setup's change, before anything is kept
    booked = _book(owner, mobile, experiment)
    listed = api.get("/api/v1/runs/", **JSON).json()["results"]
    assert [(row["id"], row["start_at"]) for row in listed] == [
        (booked.run.pk, booked.start_at.astimezone(UTC).isoformat().replace("+00:00", "Z"))
    ]

    later = booked.start_at + timedelta(hours=2)
    reservation_reschedule(
        reservation=booked, by=owner, start_at=later, end_at=later + timedelta(minutes=30)
    )
    listed = api.get("/api/v1/runs/", **JSON).json()["results"]
    assert listed[0]["start_at"] == later.astimezone(UTC).isoformat().replace("+00:00", "Z")

    before = (RUNS.current(), CALENDAR_SETUP.current())
    start = later + timedelta(hours=1)
    book_nodes(owner=owner, resource=node, start_at=start, end_at=start + timedelta(hours=1))
    assert (RUNS.current(), CALENDAR_SETUP.current()) == before
    with CaptureQueriesContext(connection) as queries:
        again = api.get("/api/v1/runs/", **JSON)
    assert again.json()["results"] == listed
    read = [q["sql"] for q in queries.captured_queries if '"runs_run"' in q["sql"]]
    assert read == [], "answered from the cache"

    reservation_cancel(reservation=booked, by=owner)
    listed = api.get("/api/v1/runs/", **JSON).json()["results"]
    assert listed[0]["state"] == "cancelled"


def test_the_list_shows_each_reservation_as_the_reservations_serializer_does(
    client_for, owner, other, admin_user, mobile, experiment
):
    """The list builds its rows from plain values (``reservations_represented``); each must be
    what ``ReservationOutput`` makes of the reservation, key for key and in the same order: a
    mobile node's booking with its run, one without a run yet, fixed nodes alone (no run even
    if one existed), the robot with a fixed node, a cancelled booking with its reasons, and
    another user's booking, which only the admin sees."""
    from bookings.choices import ReservationState
    from bookings.models import Reservation, ReservationItem
    from portal.runs.apis.reservations import ReservationOutput
    from tests.factories import FixedResourceFactory

    node, other_node = FixedResourceFactory(), FixedResourceFactory()
    start = datetime(2030, 1, 7, 10, tzinfo=UTC)

    def reservation(who, resources, hours, **fields):
        at = start + timedelta(hours=hours)
        booked = Reservation.objects.create(
            owner=who, start_at=at, end_at=at + timedelta(minutes=30), **fields
        )
        for resource in resources:
            ReservationItem.objects.create(
                reservation=booked, resource=resource, start_at=at, end_at=booked.end_at
            )
        return booked

    with_run = reservation(owner, [mobile], 0, title="sweep", state=ReservationState.CONFIRMED)
    Run.objects.create(
        reservation=with_run,
        resource=mobile,
        experiment=experiment,
        title="sweep",
        start_at=with_run.start_at,
        end_at=with_run.end_at,
        state=RunState.STAGED,
        segments=experiment.segments,
    )
    reservation(owner, [mobile], 1, override_reason="a demo", state=ReservationState.REQUESTED)
    fixed_only = reservation(owner, [node, other_node], 2)
    Run.objects.create(
        reservation=fixed_only,
        resource=mobile,
        experiment=experiment,
        title="stray",
        start_at=fixed_only.start_at,
        end_at=fixed_only.end_at,
        segments=experiment.segments,
    )
    reservation(owner, [node, mobile], 3, conflict="moved by the scheduler")
    reservation(
        owner,
        [mobile],
        4,
        state=ReservationState.CANCELLED,
        cancel_reason="rain",
        decision_reason="fine",
    )
    reservation(other, [other_node], 5, title="theirs")

    for user in (owner, admin_user):
        listed = client_for(user).get("/api/v1/reservations/", **JSON).json()["results"]
        shown = Reservation.objects.order_by("start_at", "pk")
        if user == owner:
            shown = shown.filter(owner=owner)
        expected = json.loads(json.dumps(ReservationOutput(shown, many=True).data))
        assert len(listed) == (5 if user == owner else 6)
        for got, want in zip(listed, expected, strict=True):
            assert list(got) == list(want)
            assert got == want
    assert listed[0]["run"]["state"] == "staged"
    assert listed[2]["run"] is None  # fixed nodes only
    assert listed[2]["resources"] == [node.name, other_node.name]
