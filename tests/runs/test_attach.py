"""Attaching an experiment to a booking made through the lease API, and the mail its owner
gets when someone else cancels a booking."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.contrib.auth.models import Permission
from django.core import mail
from django.utils import timezone

from bookings.choices import BookedVia, Channel, ReservationState
from bookings.models import Reservation
from bookings.services import reservations as without_run
from core.audit.models import AuditEvent
from core.events.tasks import events_dispatch_all
from portal.runs.models import Run
from portal.runs.services.reservations import reservation_attach, reservation_create
from portal.runs.services.staging import run_stage
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, UserFactory

pytestmark = pytest.mark.django_db


@pytest.fixture
def scheduler_account():
    account = UserFactory(username="testbed-scheduler")
    account.user_permissions.add(Permission.objects.get(codename="lease_inbound"))
    return account


@pytest.fixture
def leased(owner, mobile, scheduler_account) -> Reservation:
    """The robot held for ``owner`` through the lease API, without a program (30 min)."""
    start = timezone.now().replace(microsecond=0) + timedelta(hours=2)
    reservation = without_run.reservation_create(
        owner=owner,
        resources=[mobile],
        start_at=start,
        end_at=start + timedelta(minutes=30),
        title="r2lab-robot-session",
        by=scheduler_account,
        program_required=False,
        booked_via=BookedVia.SCHEDULER,
    )
    events_dispatch_all.apply()  # its booking's own e-mail, out of the tests' way
    mail.outbox.clear()
    return reservation


def _attach(client, reservation: Reservation, experiment_id: int):
    return client.post(
        f"/api/v1/reservations/{reservation.pk}/attach/",
        {"experiment": experiment_id},
        format="json",
    )


def test_the_owner_attaches_an_experiment_and_its_run_is_scheduled(
    client_for, owner, leased, experiment
):
    answer = _attach(client_for(owner), leased, experiment.pk)
    assert answer.status_code == 201, answer.json()
    run = Run.objects.get(reservation=leased)
    assert answer.json()["run"] == {"id": run.pk, "state": "scheduled"}
    assert (run.experiment, run.state) == (experiment, RunState.SCHEDULED)
    assert (run.start_at, run.end_at) == (leased.start_at, leased.end_at)
    assert run.segments == experiment.segments
    assert AuditEvent.objects.filter(action="reservation.attach", actor=owner).exists()
    # A second experiment is refused: the booking has its own.
    again = _attach(client_for(owner), leased, ExperimentFactory(owner=owner).pk)
    assert again.status_code == 409
    assert "already has its experiment" in again.json()["detail"]
    assert Run.objects.filter(reservation=leased).count() == 1


@pytest.mark.parametrize(
    ("who", "status", "says"),
    [
        ("other", 404, "No Reservation matches"),
        ("admin", 403, "Only the booking's owner"),
    ],
)
def test_only_the_owner_attaches(
    client_for, other, admin_user, leased, experiment, who, status, says
):
    user = {"other": other, "admin": admin_user}[who]
    answer = _attach(client_for(user), leased, experiment.pk)
    assert answer.status_code == status
    assert says.lower() in answer.json()["detail"].lower()
    assert not Run.objects.exists()


def test_anonymous_is_asked_to_log_in(client, leased, experiment):
    answer = client.post(
        f"/api/v1/reservations/{leased.pk}/attach/",
        {"experiment": experiment.pk},
        content_type="application/json",
    )
    assert answer.status_code in (401, 403)
    assert not Run.objects.exists()


def test_refusals_say_why_and_attach_nothing(client_for, owner, mobile, leased):
    api = client_for(owner)
    too_fast = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 2.5, "direction": "cw", "duration_s": 3.0}]
    )
    answer = _attach(api, leased, too_fast.pk)
    assert answer.status_code == 400
    assert "Segment 0" in str(answer.json())
    too_long = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3600.0}]
    )
    answer = _attach(api, leased, too_long.pk)
    assert answer.status_code == 400
    assert "only 1800 s" in str(answer.json())
    someone_elses = ExperimentFactory(owner=UserFactory())
    answer = _attach(api, leased, someone_elses.pk)
    assert answer.status_code in (403, 404)
    assert _attach(api, leased, 999999).status_code == 404
    bad = api.post(f"/api/v1/reservations/{leased.pk}/attach/", {}, format="json")
    assert bad.status_code == 400
    assert "experiment" in bad.json()["fields"]
    # A booking made in the portal comes with its experiment: nothing to attach.
    start = leased.end_at + timedelta(hours=1)
    portal = reservation_create(
        owner=owner,
        resources=[mobile],
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    )
    Run.objects.filter(reservation=portal).delete()
    answer = _attach(api, portal, ExperimentFactory(owner=owner).pk)
    assert answer.status_code == 409
    assert "lease API" in answer.json()["detail"]
    assert list(Run.objects.all()) == []


def test_a_booking_that_has_started_takes_no_experiment(client_for, owner, leased, experiment):
    Reservation.objects.filter(pk=leased.pk).update(start_at=timezone.now() - timedelta(minutes=1))
    answer = _attach(client_for(owner), leased, experiment.pk)
    assert answer.status_code == 409
    assert "before the booking starts" in answer.json()["detail"]
    leased.refresh_from_db()
    without_run.reservation_cancel(reservation=leased, by=owner)
    Reservation.objects.filter(pk=leased.pk).update(start_at=timezone.now() + timedelta(minutes=5))
    answer = _attach(client_for(owner), leased, experiment.pk)
    assert answer.status_code == 409
    assert not Run.objects.exists()


def test_a_robot_out_of_service_takes_no_experiment(client_for, owner, mobile, leased, experiment):
    mobile.held_at = timezone.now()
    mobile.hold_reason = "battery below 11.0 V"
    mobile.save()
    answer = _attach(client_for(owner), leased, experiment.pk)
    assert answer.status_code >= 400
    assert "battery below 11.0 V" in str(answer.json())
    assert not Run.objects.exists()


def test_the_attach_page_attaches_and_the_home_page_links_to_it(client, owner, leased, experiment):
    client.force_login(owner)
    home = client.get("/").content.decode()
    assert f"/reservations/{leased.pk}/attach/" in home
    page = client.get(f"/reservations/{leased.pk}/attach/")
    assert page.status_code == 200
    assert experiment.title in page.content.decode()
    answer = client.post(f"/reservations/{leased.pk}/attach/", {"experiment": experiment.pk})
    run = Run.objects.get(reservation=leased)
    assert answer.status_code == 302
    assert answer["Location"] == f"/runs/{run.pk}/"
    # Refused: said on the page, nothing more attached.
    answer = client.post(
        f"/reservations/{leased.pk}/attach/", {"experiment": experiment.pk}, follow=True
    )
    assert "already" in answer.content.decode()
    assert Run.objects.count() == 1


def test_a_run_whose_lease_was_cancelled_is_not_staged(
    owner, leased, experiment, scheduler_account
):
    run = reservation_attach(reservation=leased, experiment=experiment, by=owner)
    without_run.reservation_cancel(
        reservation=leased,
        by=scheduler_account,
        reason="cancelled by the scheduler",
        via=Channel.LEASE_API,
    )
    run_stage(run_id=run.pk, now=leased.start_at)
    run.refresh_from_db()
    assert run.state == RunState.CANCELLED


def test_the_cancellation_mail_says_who_cancelled_and_through_what(
    owner,
    leased,
    scheduler_account,
    admin_user,
    mobile,
    eager_tasks,
    django_capture_on_commit_callbacks,
):
    with django_capture_on_commit_callbacks(execute=True):
        without_run.reservation_cancel(
            reservation=leased,
            by=scheduler_account,
            reason="cancelled by the scheduler",
            via=Channel.LEASE_API,
        )
    [message] = mail.outbox
    assert message.to == [owner.email]
    assert message.subject.startswith(
        "Your booking was cancelled by testbed-scheduler (the testbed scheduler's account)"
    )
    assert (
        "testbed-scheduler (the testbed scheduler's account) cancelled your booking of mobile-1"
        in message.body
    )
    assert "through the testbed scheduler's lease API: cancelled by the scheduler" in message.body
    assert "an admin" not in message.body

    start = leased.end_at + timedelta(hours=1)
    with django_capture_on_commit_callbacks(execute=True):
        other_booking = reservation_create(
            owner=owner,
            resources=[mobile],
            start_at=start,
            end_at=start + timedelta(minutes=10),
            experiment=ExperimentFactory(owner=owner),
        )
    mail.outbox.clear()
    with django_capture_on_commit_callbacks(execute=True):
        without_run.reservation_cancel(
            reservation=other_booking, by=admin_user, reason="robot repairs", via=Channel.WEB
        )
    [message] = mail.outbox
    name = admin_user.get_username()
    assert f"{name} (an admin) cancelled your booking" in message.body
    assert "on the portal's pages: robot repairs" in message.body


def test_the_owner_cancelling_their_own_booking_gets_no_mail(
    owner, leased, eager_tasks, django_capture_on_commit_callbacks
):
    with django_capture_on_commit_callbacks(execute=True):
        without_run.reservation_cancel(reservation=leased, by=owner, via=Channel.API)
    assert leased.__class__.objects.get(pk=leased.pk).state == ReservationState.CANCELLED
    assert mail.outbox == []
