from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from bookings.choices import ReservationState
from bookings.models import Reservation
from core.errors import Conflict, InvalidInput, NotAllowed
from portal.runs.models import Run
from portal.runs.services.reservations import reservation_cancel, reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, FixedResourceFactory

pytestmark = pytest.mark.django_db


def _window(minutes_ahead: int = 60, length_min: int = 30):
    start = timezone.now() + timedelta(minutes=minutes_ahead)
    return start, start + timedelta(minutes=length_min)


def test_booking_the_mobile_node_schedules_a_run_with_a_copy_of_the_program(
    owner, mobile, experiment
):
    start, end = _window()
    reservation = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    run = Run.objects.get(reservation=reservation)
    assert run.state == RunState.SCHEDULED
    assert run.segments == experiment.segments
    assert [e.to_state for e in run.events.all()] == [RunState.SCHEDULED]
    experiment.segments = [{"velocity_mps": 1.0, "direction": "cw", "duration_s": 1.0}]
    experiment.save()
    run.refresh_from_db()
    assert len(run.segments) == 2


def test_it_rejects_overlapping_reservation(owner, other, mobile, experiment):
    start, end = _window()
    reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    theirs = ExperimentFactory(owner=other)
    with pytest.raises(Conflict, match="already booked"):
        reservation_create(
            owner=other,
            resource=mobile,
            start_at=start + timedelta(minutes=29),
            end_at=end + timedelta(minutes=29),
            experiment=theirs,
        )
    assert Reservation.objects.count() == 1


def test_back_to_back_reservations_do_not_overlap(owner, mobile, experiment):
    start, end = _window()
    reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    reservation_create(
        owner=owner,
        resource=mobile,
        start_at=end,
        end_at=end + timedelta(minutes=10),
        experiment=experiment,
    )
    assert Reservation.objects.count() == 2


def test_a_cancelled_reservation_frees_its_slot(owner, mobile, experiment):
    start, end = _window()
    first = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    reservation_cancel(reservation=first, by=owner)
    assert Run.objects.get(reservation=first).state == RunState.CANCELLED
    reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )


@pytest.mark.parametrize(
    ("change", "field", "message"),
    [
        ({"start_at": -120}, "start_at", "in the past"),
        ({"end_at": -3600}, "end_at", "after the start"),
        ({"end_at": 5 * 3600}, "end_at", "at most 4 h"),
    ],
)
def test_it_rejects_bad_windows(owner, mobile, experiment, change, field, message):
    start, end = _window(minutes_ahead=1)
    if "start_at" in change:
        start = timezone.now() + timedelta(seconds=change["start_at"])
    if "end_at" in change:
        end = start + timedelta(seconds=change["end_at"])
    with pytest.raises(InvalidInput) as excinfo:
        reservation_create(
            owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
        )
    assert message in excinfo.value.fields[field][0]
    assert not Reservation.objects.exists()


def test_the_program_must_fit_in_the_reservation(owner, mobile):
    long = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 1, "direction": "cw", "duration_s": 600}]
    )
    start = timezone.now() + timedelta(minutes=5)
    with pytest.raises(InvalidInput, match="lasts 600 s but the reservation only 300 s"):
        reservation_create(
            owner=owner,
            resource=mobile,
            start_at=start,
            end_at=start + timedelta(minutes=5),
            experiment=long,
        )


def test_the_mobile_node_needs_an_experiment_and_fixed_nodes_refuse_one(owner, mobile, experiment):
    start, end = _window()
    with pytest.raises(InvalidInput, match="Choose the experiment"):
        reservation_create(owner=owner, resource=mobile, start_at=start, end_at=end)
    fixed = FixedResourceFactory()
    with pytest.raises(InvalidInput, match="Only mobile nodes"):
        reservation_create(
            owner=owner, resource=fixed, start_at=start, end_at=end, experiment=experiment
        )
    assert reservation_create(owner=owner, resource=fixed, start_at=start, end_at=end).pk


def test_someone_elses_experiment_cannot_be_booked(other, mobile, experiment):
    start, end = _window()
    with pytest.raises(NotAllowed):
        reservation_create(
            owner=other, resource=mobile, start_at=start, end_at=end, experiment=experiment
        )


def test_a_resource_out_of_service_cannot_be_booked(owner, mobile, experiment):
    mobile.enabled = False
    mobile.save()
    start, end = _window()
    with pytest.raises(InvalidInput, match="out of service"):
        reservation_create(
            owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
        )


def test_only_owner_or_admin_cancels(owner, other, admin_user, mobile, experiment):
    start, end = _window()
    reservation = reservation_create(
        owner=owner, resource=mobile, start_at=start, end_at=end, experiment=experiment
    )
    with pytest.raises(NotAllowed):
        reservation_cancel(reservation=reservation, by=other)
    with pytest.raises(InvalidInput, match="Say why"):
        reservation_cancel(reservation=reservation, by=admin_user)
    reservation_cancel(reservation=reservation, by=admin_user, reason="roof inspection")
    reservation.refresh_from_db()
    assert reservation.state == ReservationState.CANCELLED
    with pytest.raises(Conflict, match="already cancelled"):
        reservation_cancel(reservation=reservation, by=owner)
