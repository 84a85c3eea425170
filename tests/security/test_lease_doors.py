"""A booking and its run change together through every door; staging hands an agent only a
run its booking holds.

The testbed scheduler leases the robot for a researcher, who attaches an experiment; the
scheduler then moves or cancels the lease through the lease API. And a booking changed
behind its run's back (a row written directly) never reaches the robot.
"""

from __future__ import annotations

import logging
from datetime import UTC, datetime, timedelta

import pytest
from django.contrib.auth.models import Permission
from django.utils import timezone
from rest_framework.test import APIClient

from bookings.choices import ReservationState
from bookings.models import Reservation
from core.audit.models import AuditEvent
from portal.runs import tasks
from portal.runs.models import Run
from portal.runs.services.reservations import reservation_create
from portal.runs.services.staging import run_stage, runs_due_for_staging
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, UserFactory, api_token

pytestmark = pytest.mark.django_db

LEASES = "/scheduler/resources/leases"


def _wire(value: datetime) -> str:
    return value.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


@pytest.fixture
def scheduler() -> APIClient:
    """The testbed scheduler's service account, with its API token."""
    account = UserFactory(username="testbed-scheduler")
    account.user_permissions.add(Permission.objects.get(codename="lease_inbound"))
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {api_token(account)}")
    return client


@pytest.fixture
def leased_run(scheduler, client_for, owner, mobile) -> Run:
    """mobile-1 leased for ``owner`` for 30 min two hours ahead, with a 40 s experiment."""
    start = timezone.now().replace(microsecond=0) + timedelta(hours=2)
    made = scheduler.post(
        LEASES,
        {
            "name": "r2lab-robot-session",
            "valid_from": _wire(start),
            "valid_until": _wire(start + timedelta(minutes=30)),
            "account_attributes": {"name": owner.username},
            "components": [{"name": mobile.name}],
        },
        format="json",
    )
    assert made.status_code == 200, made.json()
    reservation = Reservation.objects.get(
        public_id=made.json()["resource_response"]["resource"]["uuid"]
    )
    experiment = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 40.0}]
    )
    attached = client_for(owner).post(
        f"/api/v1/reservations/{reservation.pk}/attach/",
        {"experiment": experiment.pk},
        format="json",
    )
    assert attached.status_code == 201, attached.json()
    return Run.objects.get(reservation=reservation)


def _move(scheduler: APIClient, run: Run, *, later: timedelta, length_s: float):
    start = run.reservation.start_at + later
    return scheduler.put(
        LEASES,
        {
            "uuid": str(run.reservation.public_id),
            "valid_from": _wire(start),
            "valid_until": _wire(start + timedelta(seconds=length_s)),
        },
        format="json",
    )


def _windows(run: Run) -> tuple[tuple[datetime, datetime], tuple[datetime, datetime]]:
    run.refresh_from_db()
    run.reservation.refresh_from_db()
    return (run.reservation.start_at, run.reservation.end_at), (run.start_at, run.end_at)


def test_a_lease_moved_so_that_its_experiment_no_longer_fits_is_refused_in_the_envelope(
    scheduler, leased_run
):
    before = _windows(leased_run)
    answer = _move(scheduler, leased_run, later=timedelta(hours=3), length_s=20)
    assert answer.status_code == 409
    envelope = answer.json()
    assert set(envelope) == {"exception"}
    assert envelope["exception"]["code"] == 409
    assert "experiment" in envelope["exception"]["reason"]
    # Nothing moved: neither the booking nor its run.
    assert _windows(leased_run) == before
    assert leased_run.state == RunState.SCHEDULED
    assert not AuditEvent.objects.filter(action="reservation.reschedule").exists()


def test_a_lease_moved_with_room_for_its_experiment_moves_its_run(scheduler, leased_run):
    answer = _move(scheduler, leased_run, later=timedelta(hours=3), length_s=60)
    assert answer.status_code == 200, answer.json()
    booked, run_window = _windows(leased_run)
    assert run_window == booked
    assert booked[1] - booked[0] == timedelta(seconds=60)
    assert leased_run.state == RunState.SCHEDULED
    moved = AuditEvent.objects.get(action="reservation.reschedule")
    assert moved.data["via"] == "lease_api"


def test_a_lease_cancelled_withdraws_its_run(scheduler, leased_run):
    answer = scheduler.delete(
        LEASES, {"uuid": str(leased_run.reservation.public_id)}, format="json"
    )
    assert answer.status_code == 200, answer.json()
    assert answer.json()["resource_response"]["resource"]["status"] == "cancelled"
    leased_run.refresh_from_db()
    assert leased_run.reservation.state == ReservationState.CANCELLED
    assert leased_run.state == RunState.CANCELLED
    assert AuditEvent.objects.get(action="reservation.cancel").data["via"] == "lease_api"


@pytest.fixture
def due_run(owner, mobile) -> Run:
    """A confirmed booking with its run, starting within the staging lead."""
    start = timezone.now() + timedelta(minutes=2)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=5),
        experiment=ExperimentFactory(owner=owner),
    )
    return Run.objects.get(reservation=reservation)


# Changes of the booking row written around the services: its run does not follow.
BEHIND_ITS_BACK = {
    "moved": lambda r: {
        "start_at": r.start_at + timedelta(hours=3),
        "end_at": r.end_at + timedelta(hours=3),
    },
    "shortened": lambda r: {"end_at": r.start_at + timedelta(seconds=1)},
    "cancelled": lambda r: {"state": ReservationState.CANCELLED},
    "completed": lambda r: {"state": ReservationState.COMPLETED},
}


@pytest.mark.parametrize("door", ["sweep", "stage task"])
@pytest.mark.parametrize("change", list(BEHIND_ITS_BACK))
def test_a_run_whose_booking_changed_behind_its_back_is_not_staged_and_is_reported(
    due_run, change, door, eager_tasks, caplog
):
    Reservation.objects.filter(pk=due_run.reservation_id).update(**BEHIND_ITS_BACK[change](due_run))
    assert not runs_due_for_staging(now=timezone.now()).filter(pk=due_run.pk).exists()
    with caplog.at_level(logging.WARNING, logger="portal.runs.services.staging"):
        if door == "sweep":
            tasks.runs_sweep.apply()
        else:  # a stage task queued before the change, delivered after it
            run_stage(run_id=due_run.pk)
    due_run.refresh_from_db()
    if change == "cancelled":
        assert (due_run.state, due_run.reason) == (RunState.CANCELLED, "its booking was cancelled")
    else:
        assert due_run.state == RunState.FAILED
        assert due_run.reason.startswith("not staged: its booking")
    assert f"run {due_run.pk} held from staging" in caplog.text


def test_a_confirmed_run_in_its_booking_is_due_for_staging(due_run):
    # The guard above holds back only the runs it should.
    assert list(runs_due_for_staging(now=timezone.now())) == [due_run]
