"""Run again: the same program with the same limits in the robot's next free slot, linked to
the run it repeats (``portal/runs/services/reservations.py`` ``reservation_repeat``)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from core.errors import DomainError
from portal.runs.models import Run
from portal.runs.services import reservations as with_run
from portal.runs.services.reservations import reservation_create, reservation_repeat
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db


@pytest.fixture
def original(owner, mobile):
    experiment = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 20.0}]
    )
    start = timezone.now() + timedelta(hours=1)
    run = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=40),
        experiment=experiment,
    ).run
    Run.objects.filter(pk=run.pk).update(
        provenance={
            "format_version": 1,
            "staged": {"limits": {"max_velocity_mps": 1.2, "max_accel_mps2": 0.3}},
        }
    )
    run.refresh_from_db()
    return run


def _book(owner, mobile, start, seconds):
    return reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(seconds=seconds),
        experiment=ExperimentFactory(owner=owner),
    )


def test_it_books_the_same_program_and_limits_in_the_next_free_slot(
    owner, mobile, original, settings
):
    settings.RUN_REPEAT_LEAD_S = 30
    now = timezone.now().replace(microsecond=0)
    # The robot is busy from 30 s to 100 s from now: the repeat (40 s) goes after that.
    busy = _book(owner, mobile, now + timedelta(seconds=30), 70)
    # The experiment changed since: the repeat runs what was run.
    original.experiment.segments = [{"velocity_mps": 0.9, "direction": "ccw", "duration_s": 5}]
    original.experiment.save()

    again = reservation_repeat(run=original, by=owner, now=now).run
    assert again.repeat_of_id == original.pk
    assert again.segments == original.segments
    assert again.title == original.title
    assert again.limits == {"max_velocity_mps": 1.2, "max_accel_mps2": 0.3}
    assert again.start_at == busy.end_at
    assert again.end_at - again.start_at == timedelta(seconds=40)
    assert again.reservation.owner == owner
    assert list(original.repeats.all()) == [again]


def test_a_slot_taken_between_the_look_and_the_booking_is_looked_for_again(
    owner, mobile, original, monkeypatch
):
    now = timezone.now().replace(microsecond=0)
    taken = _book(owner, mobile, now + timedelta(minutes=5), 40)
    looks = []
    real = with_run.resource_first_free

    def stale_first(**kwargs):
        looks.append(kwargs["earliest"])
        if len(looks) == 1:  # the first look does not see the booking just made
            return taken.start_at, taken.end_at
        return real(**kwargs)

    monkeypatch.setattr(with_run, "resource_first_free", stale_first)
    again = reservation_repeat(run=original, by=owner, now=now).run
    assert len(looks) == 2
    assert again.start_at != taken.start_at


def test_a_robot_out_of_service_is_refused_with_the_reason(owner, mobile, original):
    mobile.hold_reason = "emergency stop latched"
    mobile.save()
    with pytest.raises(DomainError) as caught:
        reservation_repeat(run=original, by=owner)
    assert "is out of service: emergency stop latched" in caught.value.message
    assert Run.objects.count() == 1


def test_run_again_through_the_api_for_the_owner_the_admin_and_nobody_else(
    client_for, owner, other, admin_user, original
):
    url = f"/api/v1/runs/{original.pk}/again/"
    assert client_for(None).post(url).status_code in (401, 403)
    assert client_for(other).post(url).status_code == 404
    mine = client_for(owner).post(url)
    assert mine.status_code == 201, mine.json()
    repeat = Run.objects.get(pk=mine.json()["run"]["id"])
    assert repeat.repeat_of_id == original.pk
    assert client_for(owner).get(f"/api/v1/runs/{repeat.pk}/").json()["repeat_of"] == original.pk
    # An admin books it again for its owner.
    theirs = client_for(admin_user).post(url)
    assert theirs.status_code == 201, theirs.json()
    assert theirs.json()["owner"] == "alice"


def test_an_empty_idempotency_key_is_refused_and_books_nothing(client_for, owner, original):
    answer = client_for(owner).post(f"/api/v1/runs/{original.pk}/again/", HTTP_X_IDEMPOTENCY_KEY="")
    assert answer.status_code == 400
    assert "X-Idempotency-Key" in answer.json()["detail"]
    assert Run.objects.count() == 1
