"""The queue ("as soon as possible"): booked through the same service as every booking, in
fair-share order, within the horizon and the allowed hours; expiring with the reason; paused,
resumed and reordered only by an admin, audited. Every clock here is fixed (``now=``)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from bookings.choices import ReservationState
from bookings.models import Reservation, ReservationItem
from core.audit.models import AuditEvent
from core.errors import Conflict, InvalidInput, NotAllowed
from portal.queue.allocation import queue_allocate
from portal.queue.models import QueueRequest, RequestState
from portal.queue.selectors import queue_places, robot_use_s
from portal.queue.services import (
    queue_pause,
    queue_request_cancel,
    queue_request_reorder,
    queue_request_submit,
    queue_resume,
)
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, FixedResourceFactory

pytestmark = pytest.mark.django_db

# A Monday morning in the testbed's winter (UTC is Lisbon's time then).
NOW = datetime(2030, 1, 7, 9, 0, tzinfo=UTC)
JSON = {"HTTP_ACCEPT": "application/json"}


def _busy(owner, mobile, start: datetime, minutes: int, state=ReservationState.CONFIRMED):
    """A booking already on the calendar, written straight into its tables."""
    reservation = Reservation.objects.create(
        owner=owner, start_at=start, end_at=start + timedelta(minutes=minutes), state=state
    )
    ReservationItem.objects.create(
        reservation=reservation,
        resource=mobile,
        start_at=reservation.start_at,
        end_at=reservation.end_at,
        active=state in (ReservationState.CONFIRMED, ReservationState.REQUESTED),
    )
    return reservation


def _submit(owner, mobile, experiment=None, **kwargs):
    kwargs.setdefault("latest_end_at", NOW + timedelta(days=2))
    return queue_request_submit(
        owner=owner,
        experiment=experiment or ExperimentFactory(owner=owner),
        robot=mobile,
        now=NOW,
        **kwargs,
    )


def test_a_request_is_booked_in_the_first_free_slot_through_the_booking_service(
    owner, other, mobile, settings
):
    settings.QUEUE_LEAD_S = 120
    # Taken from the lead on for an hour: the first slot begins where that booking ends.
    _busy(other, mobile, NOW + timedelta(minutes=1), 60)
    request = _submit(owner, mobile)
    assert request.state == RequestState.WAITING
    assert request.duration_s == 60  # a 6 s program, rounded up to a minute

    done = queue_allocate(now=NOW)
    request.refresh_from_db()
    assert done.booked == [request.pk]
    assert request.state == RequestState.BOOKED
    reservation = request.reservation
    assert reservation.owner == owner
    assert reservation.start_at == NOW + timedelta(minutes=61)
    assert reservation.end_at == reservation.start_at + timedelta(seconds=60)
    assert reservation.run.state == RunState.SCHEDULED  # a run, as every robot booking has
    audit = AuditEvent.objects.get(action="reservation.create", target_id=str(reservation.pk))
    assert audit.data["via"] == "queue"
    assert AuditEvent.objects.filter(action="queue.book", target_id=str(request.pk)).exists()
    # Nothing left to do: a second pass books nothing more.
    assert queue_allocate(now=NOW).booked == []


def test_the_order_is_less_recent_use_first_then_who_asked_first(owner, other, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    settings.QUEUE_FAIR_SHARE_WINDOW_S = 14 * 86400
    third = type(owner).objects.create(username="dora")
    # Use over the window: alice 90 min last week, bob 30 min, dora none; a booking of
    # alice's before the window and a cancelled one of bob's do not count.
    _busy(owner, mobile, NOW - timedelta(days=3), 90)
    _busy(owner, mobile, NOW - timedelta(days=30), 600)
    _busy(other, mobile, NOW - timedelta(days=2), 30)
    _busy(other, mobile, NOW - timedelta(days=1), 300, state=ReservationState.CANCELLED)
    assert robot_use_s([owner.pk, other.pk, third.pk], now=NOW) == {
        owner.pk: 5400.0,
        other.pk: 1800.0,
        third.pk: 0.0,
    }
    # One free hour before a long block: only one request fits before the block ends.
    _busy(owner, mobile, NOW + timedelta(minutes=60), 24 * 60)
    asked = [
        _submit(owner, mobile, duration_s=3600),
        _submit(other, mobile, duration_s=3600),
        _submit(third, mobile, duration_s=3600),
    ]
    places = queue_places(now=NOW)
    # The rule, computed here: ascending use, then submission.
    use = {owner.pk: 5400 + 24 * 3600, other.pk: 1800, third.pk: 0}
    expected = sorted(asked, key=lambda r: (use[r.owner_id], r.submitted_at, r.pk))
    assert [places[r.pk].position for r in expected] == [1, 2, 3]
    assert places[expected[0].pk].estimated_start_at == NOW
    assert places[expected[1].pk].estimated_start_at == NOW + timedelta(minutes=60 + 24 * 60)

    done = queue_allocate(now=NOW)
    assert done.booked[0] == expected[0].pk
    first = QueueRequest.objects.get(pk=expected[0].pk).reservation
    assert first.start_at == NOW
    # The others follow the block, in the same order.
    starts = [QueueRequest.objects.get(pk=r.pk).reservation.start_at for r in expected[1:]]
    assert starts == sorted(starts)


def test_nights_only_is_booked_at_the_first_night(owner, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    request = _submit(owner, mobile, hours_from=22, hours_to=6)
    queue_allocate(now=NOW)
    request.refresh_from_db()
    assert request.reservation.start_at == datetime(2030, 1, 7, 22, 0, tzinfo=UTC)


def test_beyond_the_horizon_it_waits_with_the_reason_and_an_estimate(owner, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    settings.QUEUE_HORIZON_S = 86400
    later = _submit(
        owner,
        mobile,
        earliest_at=NOW + timedelta(days=3),
        latest_end_at=NOW + timedelta(days=5),
    )
    assert queue_allocate(now=NOW).booked == []
    later.refresh_from_db()
    assert later.state == RequestState.WAITING
    assert "beyond the queue's horizon" in later.reason
    assert queue_places(now=NOW)[later.pk].estimated_start_at == NOW + timedelta(days=3)
    # Two days on, the horizon reaches it.
    assert queue_allocate(now=NOW + timedelta(days=2, hours=1)).booked == [later.pk]


def test_a_request_that_cannot_end_in_time_expires_with_the_reason(owner, other, mobile, settings):
    settings.QUEUE_LEAD_S = 0
    _busy(other, mobile, NOW, 5 * 60)
    request = _submit(owner, mobile, latest_end_at=NOW + timedelta(hours=4))
    assert queue_allocate(now=NOW).booked == []
    request.refresh_from_db()
    assert request.state == RequestState.WAITING
    assert request.reason  # why it waits
    done = queue_allocate(now=NOW + timedelta(hours=3, minutes=59, seconds=30))
    request.refresh_from_db()
    assert done.expired == [request.pk]
    assert request.state == RequestState.EXPIRED
    assert "before its latest end" in request.reason


def test_a_waiting_request_is_cancelled_at_once_a_booked_one_is_not(owner, other, mobile):
    waiting = _submit(owner, mobile, earliest_at=NOW + timedelta(days=1))
    with pytest.raises(NotAllowed):
        queue_request_cancel(request=waiting, by=other)
    cancelled = queue_request_cancel(request=waiting, by=owner, reason="changed my mind")
    assert (cancelled.state, cancelled.reason) == (RequestState.CANCELLED, "changed my mind")
    assert queue_allocate(now=NOW).booked == []
    booked = _submit(owner, mobile)
    queue_allocate(now=NOW)
    with pytest.raises(Conflict, match="cancel its reservation"):
        queue_request_cancel(request=booked, by=owner)


def test_only_an_admin_pauses_resumes_and_reorders_and_each_is_audited(
    owner, other, admin_user, mobile, settings
):
    settings.QUEUE_LEAD_S = 0
    with pytest.raises(NotAllowed):
        queue_pause(by=owner, reason="mine")
    with pytest.raises(InvalidInput):
        queue_pause(by=admin_user, reason=" ")
    queue_pause(by=admin_user, reason="robot repaired tomorrow")
    mine = _submit(owner, mobile, duration_s=3600)
    theirs = _submit(other, mobile, duration_s=3600)
    paused = queue_allocate(now=NOW)
    assert (paused.paused, paused.booked, paused.waiting) == (True, [], 2)

    with pytest.raises(NotAllowed):
        queue_request_reorder(request=theirs, priority=5, by=owner, reason="please")
    with pytest.raises(InvalidInput):
        queue_request_reorder(request=theirs, priority=5, by=admin_user, reason="")
    queue_request_reorder(request=theirs, priority=5, by=admin_user, reason="deadline Friday")
    assert [queue_places(now=NOW)[r.pk].position for r in (theirs, mine)] == [1, 2]

    queue_resume(by=admin_user)
    queue_allocate(now=NOW)
    theirs.refresh_from_db()
    mine.refresh_from_db()
    assert theirs.reservation.start_at < mine.reservation.start_at
    actions = list(
        AuditEvent.objects.filter(action__startswith="queue.").values_list("action", flat=True)
    )
    for action in ("queue.pause", "queue.reorder", "queue.resume"):
        assert action in actions
    assert AuditEvent.objects.get(action="queue.reorder").reason == "deadline Friday"


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"latest_end_at": NOW - timedelta(hours=1)}, "latest_end_at"),
        ({"latest_end_at": NOW + timedelta(days=400)}, "latest_end_at"),
        ({"duration_s": 2}, "duration_s"),
        ({"duration_s": 10**7}, "duration_s"),
        ({"hours_from": 22}, "hours_to"),
        ({"hours_from": 5, "hours_to": 5}, "hours_to"),
    ],
)
def test_a_request_that_could_never_be_booked_is_refused_and_nothing_is_queued(
    owner, mobile, change, field
):
    with pytest.raises(InvalidInput) as refused:
        _submit(owner, mobile, **change)
    assert field in refused.value.fields
    assert not QueueRequest.objects.exists()


def test_a_program_over_the_robots_limit_or_a_fixed_node_as_the_robot_is_refused(owner, mobile):
    fast = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 9.0, "direction": "cw", "duration_s": 3.0}]
    )
    with pytest.raises(InvalidInput, match="Segment 0"):
        _submit(owner, mobile, experiment=fast)
    with pytest.raises(InvalidInput) as refused:
        _submit(owner, FixedResourceFactory())
    assert "robot" in refused.value.fields
    assert not QueueRequest.objects.exists()


def test_through_the_api_the_owner_sees_the_place_and_the_estimate(
    api, client_for, owner, other, mobile, experiment, settings
):
    settings.QUEUE_HORIZON_S = 60  # nothing is booked: every request waits with an estimate
    body = {
        "experiment": experiment.pk,
        "robot": mobile.name,
        "earliest_at": "2031-03-03T10:00:00Z",
        "latest_end_at": "2031-03-05T10:00:00Z",
    }
    made = api.post("/api/v1/queue/", body, format="json")
    assert made.status_code == 201, made.content
    answer = made.json()
    assert (answer["state"], answer["position"]) == ("waiting", 1)
    assert answer["estimated_start_at"] == "2031-03-03T10:00:00Z"
    listed = api.get("/api/v1/queue/", **JSON).json()["results"]
    assert [row["id"] for row in listed] == [answer["id"]]
    # Another user neither sees it nor cancels it.
    assert client_for(other).get("/api/v1/queue/", **JSON).json()["results"] == []
    assert client_for(other).delete(f"/api/v1/queue/{answer['id']}/").status_code == 404
    # Bad input: a clear error, nothing queued.
    for bad in (
        {**body, "robot": "nowhere"},
        {**body, "latest_end_at": "2031-03-03T10:00:00Z"},
        {**body, "experiment": 999999},
    ):
        refused = api.post("/api/v1/queue/", bad, format="json")
        assert refused.status_code in (400, 404), refused.content
    assert QueueRequest.objects.count() == 1
    gone = api.delete(f"/api/v1/queue/{answer['id']}/", {"reason": "no longer"}, format="json")
    assert gone.status_code == 200
    assert gone.json()["state"] == "cancelled"
    # Pausing is staff's: the researcher is refused.
    assert api.post("/api/v1/queue/pause/", {"reason": "x"}, format="json").status_code == 403
