"""Approval, maintenance windows, audit trail, e-mails, idempotent creation, availability."""

from __future__ import annotations

from datetime import datetime, timedelta

import pytest
from django.core import mail
from django.db import DatabaseError, IntegrityError, transaction
from django.utils import timezone

from bookings.choices import ReservationState
from bookings.events import reservation_event_record
from bookings.models import Reservation
from bookings.reminders import reservation_remind, reservations_due_for_reminder
from bookings.services import blackout_create
from bookings.tasks import reservations_remind
from core.audit.models import AuditEvent
from core.errors import Conflict, InvalidInput, NotAllowed
from portal.runs.services.reservations import (
    reservation_cancel,
    reservation_create,
    reservation_decide,
    reservation_reschedule,
)
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, FixedResourceFactory, UserFactory

pytestmark = pytest.mark.django_db


def _slot(hours_ahead: float = 24, length_h: float = 1):
    start = timezone.now() + timedelta(hours=hours_ahead)
    return start, start + timedelta(hours=length_h)


def test_a_resource_needing_approval_holds_the_slot_until_an_admin_decides(
    owner, other, admin_user, mobile, experiment, eager_tasks, django_capture_on_commit_callbacks
):
    mobile.requires_approval = True
    mobile.save()
    start, end = _slot()
    with django_capture_on_commit_callbacks(execute=True):
        reservation = reservation_create(
            owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
        )
    assert reservation.state == ReservationState.REQUESTED
    assert {m.subject.split(":")[0] for m in mail.outbox} == {"Booking request received"}
    assert "charlie@example.org" in mail.outbox[0].to  # admins learn of pending requests
    with pytest.raises(Conflict, match="already booked"):
        reservation_create(
            owner=other,
            resource=mobile,
            start_at=start,
            end_at=end,
            experiment=ExperimentFactory(owner=other),
        )
    with pytest.raises(NotAllowed):
        reservation_decide(reservation=reservation, by=other, approve=True)
    mail.outbox.clear()
    with django_capture_on_commit_callbacks(execute=True):
        reservation_decide(reservation=reservation, by=admin_user, approve=True, reason="ok")
    reservation.refresh_from_db()
    assert reservation.state == ReservationState.CONFIRMED
    assert mail.outbox[0].subject.startswith("Booking approved")
    assert mail.outbox[0].to == ["alice@example.org"]
    with pytest.raises(Conflict, match="not awaiting approval"):
        reservation_decide(reservation=reservation, by=admin_user, approve=False, reason="x")


def test_a_rejection_needs_a_reason_frees_the_slot_and_cancels_the_run(
    owner, admin_user, mobile, experiment, eager_tasks, django_capture_on_commit_callbacks
):
    mobile.requires_approval = True
    mobile.save()
    start, end = _slot()
    reservation = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    with pytest.raises(InvalidInput, match="Say why"):
        reservation_decide(reservation=reservation, by=admin_user, approve=False)
    with django_capture_on_commit_callbacks(execute=True):
        reservation_decide(
            reservation=reservation, by=admin_user, approve=False, reason="roof closed"
        )
    reservation.refresh_from_db()
    assert reservation.state == ReservationState.REJECTED
    assert reservation.run.state == RunState.CANCELLED
    assert "roof closed" in mail.outbox[-1].body
    reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )


def test_admins_book_without_waiting_for_approval(admin_user):
    node = FixedResourceFactory(requires_approval=True)
    start, end = _slot()
    reservation = reservation_create(owner=admin_user, resource=node, start_at=start, end_at=end)
    assert reservation.state == ReservationState.CONFIRMED


def test_a_blackout_blocks_new_bookings_and_flags_existing_ones(
    owner, admin_user, eager_tasks, django_capture_on_commit_callbacks
):
    node = FixedResourceFactory()
    start, end = _slot()
    existing = reservation_create(owner=owner, resource=node, start_at=start, end_at=end)
    with pytest.raises(NotAllowed):
        blackout_create(by=owner, start_at=start, end_at=end, reason="x", resources=[node])
    # One that began under way is declared; one begun long ago refused, naming its start.
    long_ago = timezone.now() - timedelta(days=8)
    with pytest.raises(InvalidInput, match="at most 7 days ago") as refused:
        blackout_create(by=admin_user, start_at=long_ago, end_at=end, reason="x", resources=[node])
    assert "start_at" in refused.value.fields
    with django_capture_on_commit_callbacks(execute=True):
        _blackout, conflicts = blackout_create(
            by=admin_user,
            start_at=start - timedelta(hours=1),
            end_at=end + timedelta(hours=2),
            reason="antenna replacement",
            resources=[node],
        )
    assert conflicts == [existing]
    existing.refresh_from_db()
    assert "antenna replacement" in existing.conflict
    assert existing.state == ReservationState.CONFIRMED  # flagged, not silently cancelled
    message = mail.outbox[-1]
    assert message.subject.startswith("Maintenance overlaps a booking")
    assert set(message.to) == {"alice@example.org", "charlie@example.org"}
    with pytest.raises(Conflict, match="Maintenance “antenna replacement”"):
        reservation_create(
            owner=owner, resource=node, start_at=end, end_at=end + timedelta(hours=1)
        )
    other_node = FixedResourceFactory()
    reservation_create(
        owner=owner, resource=other_node, start_at=end, end_at=end + timedelta(hours=1)
    )
    blackout_create(
        by=admin_user,
        start_at=end + timedelta(days=1),
        end_at=end + timedelta(days=2),
        reason="roof works",
        all_resources=True,
    )
    with pytest.raises(Conflict, match="roof works"):
        reservation_create(
            owner=owner,
            resource=other_node,
            start_at=end + timedelta(days=1, hours=1),
            end_at=end + timedelta(days=1, hours=2),
        )


def test_an_admin_cancelling_someone_elses_booking_tells_them_why(
    owner, admin_user, eager_tasks, django_capture_on_commit_callbacks
):
    start, end = _slot()
    reservation = reservation_create(
        owner=owner, resource=FixedResourceFactory(), start_at=start, end_at=end
    )
    with django_capture_on_commit_callbacks(execute=True):
        reservation_cancel(reservation=reservation, by=admin_user, reason="storm warning")
    assert mail.outbox[-1].subject.startswith("Your booking was cancelled by charlie (an admin)")
    assert "charlie (an admin) cancelled your booking" in mail.outbox[-1].body
    assert "storm warning" in mail.outbox[-1].body


def test_reminders_go_out_once(owner, eager_tasks, django_capture_on_commit_callbacks):
    start, end = _slot(hours_ahead=0.5)
    with django_capture_on_commit_callbacks(execute=True):
        reservation = reservation_create(
            owner=owner, resource=FixedResourceFactory(), start_at=start, end_at=end
        )
        reservation_create(
            owner=owner,
            resource=FixedResourceFactory(),
            start_at=start + timedelta(hours=5),
            end_at=end + timedelta(hours=5),
        )
    assert reservations_due_for_reminder(now=timezone.now()) == [reservation.pk]
    mail.outbox.clear()
    with django_capture_on_commit_callbacks(execute=True):
        reservations_remind()
    with django_capture_on_commit_callbacks(execute=True):
        reservations_remind()
    assert [m.subject.split(":")[0] for m in mail.outbox] == ["Reminder"]
    assert reservations_due_for_reminder(now=timezone.now()) == []


def test_a_reminder_is_written_once_by_the_database_too(owner):
    start, end = _slot(hours_ahead=0.5)
    reservation = reservation_create(
        owner=owner, resource=FixedResourceFactory(), start_at=start, end_at=end
    )
    assert reservation_remind(reservation_id=reservation.pk)
    assert not reservation_remind(reservation_id=reservation.pk)
    # Two sweeps that both looked before either wrote: the second write is refused.
    with pytest.raises(IntegrityError), transaction.atomic():
        reservation_event_record("reservation.starting_soon", reservation, by=None, via="")


def test_rescheduling_checks_everything_again(owner, other):
    node = FixedResourceFactory()
    start, end = _slot()
    mine = reservation_create(owner=owner, resource=node, start_at=start, end_at=end)
    reservation_create(
        owner=other,
        resource=node,
        start_at=end + timedelta(hours=1),
        end_at=end + timedelta(hours=2),
    )
    moved = reservation_reschedule(
        reservation=mine,
        by=owner,
        start_at=start + timedelta(minutes=30),
        end_at=end + timedelta(minutes=30),
    )
    assert moved.items.get().start_at == start + timedelta(minutes=30)
    with pytest.raises(Conflict, match="already booked"):
        reservation_reschedule(
            reservation=mine,
            by=owner,
            start_at=end + timedelta(minutes=30),
            end_at=end + timedelta(hours=1, minutes=30),
        )
    with pytest.raises(NotAllowed):
        reservation_reschedule(reservation=mine, by=other, start_at=start, end_at=end)


def test_every_change_is_in_the_append_only_audit_log(owner, admin_user, client_for):
    node = FixedResourceFactory()
    start, end = _slot()
    response = client_for(owner).post(
        "/api/v1/reservations/",
        {"resource": node.name, "start_at": start.isoformat(), "end_at": end.isoformat()},
        format="json",
        REMOTE_ADDR="192.0.2.7",
    )
    assert response.status_code == 201
    reservation = Reservation.objects.get()
    reservation_cancel(reservation=reservation, by=admin_user, reason="storm", ip="192.0.2.9")
    events = list(
        AuditEvent.objects.order_by("pk").values_list("action", "actor_name", "ip", "reason")
    )
    assert events == [
        ("reservation.create", "alice", "192.0.2.7", ""),
        ("reservation.cancel", "charlie", "192.0.2.9", "storm"),
    ]
    event = AuditEvent.objects.first()
    with pytest.raises(DatabaseError, match="append-only"), transaction.atomic():
        AuditEvent.objects.filter(pk=event.pk).update(reason="edited")
    with pytest.raises(DatabaseError, match="append-only"), transaction.atomic():
        AuditEvent.objects.filter(pk=event.pk).delete()


def test_an_idempotency_key_replays_the_answer_instead_of_booking_twice(owner, client_for):
    node = FixedResourceFactory()
    start, end = _slot()
    body = {"resource": node.name, "start_at": start.isoformat(), "end_at": end.isoformat()}
    client = client_for(owner)
    first = client.post("/api/v1/reservations/", body, format="json", HTTP_X_IDEMPOTENCY_KEY="k-1")
    again = client.post("/api/v1/reservations/", body, format="json", HTTP_X_IDEMPOTENCY_KEY="k-1")
    assert first.status_code == again.status_code == 201
    assert again.json()["id"] == first.json()["id"]
    assert again["Idempotent-Replayed"] == "true"
    assert Reservation.objects.count() == 1
    changed = dict(body, end_at=(end + timedelta(hours=1)).isoformat())
    reused = client.post(
        "/api/v1/reservations/", changed, format="json", HTTP_X_IDEMPOTENCY_KEY="k-1"
    )
    assert reused.status_code == 422
    # Without a key a repeat is a new request, refused because the slot is taken.
    assert client.post("/api/v1/reservations/", body, format="json").status_code == 409


def test_a_concurrent_duplicate_with_the_same_key_gets_409(owner, client_for):
    from core.audit.models import IdempotencyKey

    node = FixedResourceFactory()
    start, end = _slot()
    body = {"resource": node.name, "start_at": start.isoformat(), "end_at": end.isoformat()}
    client = client_for(owner)
    # The first request has claimed the key and is still running (no status yet).
    first = client.post("/api/v1/reservations/", body, format="json", HTTP_X_IDEMPOTENCY_KEY="k-2")
    IdempotencyKey.objects.filter(key="k-2").update(status=None)
    duplicate = client.post(
        "/api/v1/reservations/", body, format="json", HTTP_X_IDEMPOTENCY_KEY="k-2"
    )
    assert first.status_code == 201
    assert duplicate.status_code == 409
    assert "still being handled" in duplicate.json()["detail"]


def test_availability_lists_the_free_intervals(owner, admin_user, client_for):
    node = FixedResourceFactory(name="node-03")
    day = timezone.now().replace(microsecond=0) + timedelta(days=3)
    reservation_create(
        owner=owner,
        resource=node,
        start_at=day + timedelta(hours=2),
        end_at=day + timedelta(hours=3),
    )
    blackout_create(
        by=admin_user,
        start_at=day + timedelta(hours=5),
        end_at=day + timedelta(hours=6),
        reason="service",
        resources=[node],
    )
    response = client_for(owner).get(
        "/api/v1/resources/node-03/availability/",
        {"start": day.isoformat(), "end": (day + timedelta(hours=8)).isoformat()},
    )
    assert response.status_code == 200
    free = [
        (datetime.fromisoformat(f["start"]), datetime.fromisoformat(f["end"]))
        for f in response.json()["free"]
    ]
    hours = [((s - day).total_seconds() / 3600, (e - day).total_seconds() / 3600) for s, e in free]
    assert hours == [(0, 2), (3, 5), (6, 8)]
    too_long = client_for(owner).get(
        "/api/v1/resources/node-03/availability/",
        {"start": day.isoformat(), "end": (day + timedelta(days=90)).isoformat()},
    )
    assert too_long.status_code == 400


def test_others_bookings_show_only_as_busy(owner, other, client_for):
    node = FixedResourceFactory()
    start, end = _slot()
    reservation_create(owner=owner, resource=node, start_at=start, end_at=end, title="secret plan")
    busy = client_for(other).get(
        "/api/v1/reservations/busy/", {"start": start.isoformat(), "end": end.isoformat()}
    )
    assert busy.status_code == 200
    [entry] = busy.json()
    assert set(entry) == {"resources", "start_at", "end_at", "state"}
    assert "secret" not in str(busy.json())


def test_the_quota_endpoints_show_usage_and_check_a_booking(owner, admin_user, client_for):
    node = FixedResourceFactory()
    created = client_for(admin_user).post(
        "/api/v1/quota-policies/",
        {"name": "Daily", "user": "alice", "period": "day", "max_hours": 1},
        format="json",
    )
    assert created.status_code == 201
    assert AuditEvent.objects.filter(action="quota.create").count() == 1
    start, end = _slot(length_h=2)
    check = client_for(owner).post(
        "/api/v1/reservations/check/",
        {"resources": [node.name], "start_at": start.isoformat(), "end_at": end.isoformat()},
        format="json",
    )
    assert check.status_code == 200
    assert check.json()["fits"] is False
    assert "allows 1 h per day" in check.json()["quota"][0]
    assert Reservation.objects.count() == 0  # checking changes nothing
    usage = client_for(owner).get("/api/v1/quota/").json()["policies"]
    assert usage[0]["policy"] == "Daily"
    assert usage[0]["remaining_hours"] == 1
    changed = client_for(admin_user).patch(
        f"/api/v1/quota-policies/{created.json()['id']}/", {"max_hours": 3}, format="json"
    )
    assert changed.status_code == 200
    event = AuditEvent.objects.get(action="quota.change")
    assert (event.data["before"]["max_hours"], event.data["after"]["max_hours"]) == (1.0, 3.0)
    assert (
        client_for(owner).post("/api/v1/quota-policies/", {"name": "x"}, format="json").status_code
        == 403
    )


def test_a_reservation_can_hold_several_resources(owner):
    nodes = [FixedResourceFactory() for _ in range(3)]
    start, end = _slot()
    reservation = reservation_create(owner=owner, resources=nodes, start_at=start, end_at=end)
    assert reservation.items.count() == 3
    with pytest.raises(Conflict):
        reservation_create(
            owner=UserFactory(username="zed"), resources=[nodes[2]], start_at=start, end_at=end
        )
    with pytest.raises(InvalidInput, match="listed twice"):
        reservation_create(
            owner=owner,
            resources=[nodes[0], nodes[0]],
            start_at=end,
            end_at=end + timedelta(hours=1),
        )


def test_the_live_check_names_resources_as_they_are_now(owner, client_for):
    """The check reads resources from a kept map: a resource renamed, taken out of service or
    added is seen by the next check, and a name that is no resource is refused as before."""
    node = FixedResourceFactory(name="node-07")
    start, end = _slot()

    def check(*names: object) -> dict:
        answer = client_for(owner).post(
            "/api/v1/reservations/check/",
            {"resources": list(names), "start_at": start.isoformat(), "end_at": end.isoformat()},
            format="json",
        )
        return {"status": answer.status_code, **answer.json()}

    assert check("node-07")["fits"] is True
    node.enabled = False
    node.save()
    [problem] = check("node-07")["problems"]
    assert (problem["code"], problem["message"]) == ("out_of_service", "node-07 is out of service.")
    FixedResourceFactory(name="node-08")
    assert check("node-08")["fits"] is True
    refused = check("node-99")
    assert refused["status"] == 400
    assert "Object with name=node-99 does not exist." in str(refused)
    assert check({"name": "node-08"})["status"] == 400
    assert check(True)["status"] == 400
