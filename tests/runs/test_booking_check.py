"""The calendar's live check and booking say the same thing about the same booking.

Each case sets up one reason to refuse (or none), asks the live check, then tries to book. The
check's first problem must be exactly what booking raises (same kind, field and message), and
"fits" must mean the booking is made. Every refusal reason of ``bookings.rules`` is in the table.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest

from bookings.models import Blackout, QuotaPolicy, Reservation, Resource
from bookings.rules import QuotaExceeded
from portal.errors import Conflict, DomainError, InvalidInput
from portal.experiments.models import Experiment
from portal.runs.services.booking import booking_check, booking_create
from tests.factories import (
    ExperimentFactory,
    FixedResourceFactory,
    MobileResourceFactory,
    UserFactory,
)

pytestmark = pytest.mark.django_db

NOW = datetime(2030, 6, 3, 8, 0, tzinfo=UTC)
START = NOW + timedelta(hours=2)
END = START + timedelta(minutes=30)


@dataclass
class Case:
    """What to book, after ``setup`` made the world refuse it (or not)."""

    resources: list[Resource]
    experiment: Experiment | None
    start_at: datetime = START
    end_at: datetime = END


def _program(owner, *velocities_mps: float, duration_s: float = 60.0) -> Experiment:
    # Stored as written: the point is what booking checks, not what experiment_create allows.
    return ExperimentFactory(
        owner=owner,
        segments=[
            {"velocity_mps": v, "direction": "cw", "duration_s": duration_s} for v in velocities_mps
        ],
    )


def fits_on_a_fixed_node(owner) -> Case:
    return Case([FixedResourceFactory()], None)


def fits_on_the_robot(owner) -> Case:
    return Case([MobileResourceFactory()], _program(owner, 1.0))


def end_before_start(owner) -> Case:
    return Case([FixedResourceFactory()], None, start_at=END, end_at=START)


def start_in_the_past(owner) -> Case:
    return Case([FixedResourceFactory()], None, start_at=NOW - timedelta(minutes=5))


def too_long(owner) -> Case:
    return Case([FixedResourceFactory()], None, end_at=START + timedelta(hours=5))


def out_of_service(owner) -> Case:
    return Case([FixedResourceFactory(enabled=False)], None)


def robot_held_by_its_health_check(owner) -> Case:
    return Case(
        [MobileResourceFactory(hold_reason="emergency stop latched", held_at=NOW)],
        _program(owner, 1.0),
    )


def robot_without_experiment(owner) -> Case:
    return Case([MobileResourceFactory()], None)


def experiment_on_a_fixed_node(owner) -> Case:
    return Case([FixedResourceFactory()], _program(owner, 1.0))


def two_robots(owner) -> Case:
    second = MobileResourceFactory(name="mobile-2")
    return Case([MobileResourceFactory(), second], _program(owner, 1.0))


def too_fast_for_this_robot(owner) -> Case:
    slow = MobileResourceFactory(name="mobile-slow", max_velocity_mps=0.5)
    MobileResourceFactory()  # a faster robot exists: the booked one decides
    return Case([slow], _program(owner, 0.4, 0.8))


def program_longer_than_the_slot(owner) -> Case:
    return Case([MobileResourceFactory()], _program(owner, 1.0, duration_s=3600.0))


def maintenance(owner) -> Case:
    node = FixedResourceFactory()
    blackout = Blackout.objects.create(
        start_at=START - timedelta(hours=1), end_at=END, reason="mast repair"
    )
    blackout.resources.set([node])
    return Case([node], None)


def already_booked(owner) -> Case:
    node = FixedResourceFactory()
    booking_create(
        owner=UserFactory(username="zed"),
        resource=node,
        start_at=START + timedelta(minutes=10),
        end_at=END + timedelta(minutes=10),
        now=NOW,
    )
    return Case([node], None)


def over_quota(owner) -> Case:
    QuotaPolicy.objects.create(name="short", max_length_s=600)
    return Case([FixedResourceFactory()], None)


CASES: list[tuple[Callable[[Any], Case], str | None, type[DomainError] | None, str]] = [
    # (setup, problem code, error booking raises, field)
    (fits_on_a_fixed_node, None, None, ""),
    (fits_on_the_robot, None, None, ""),
    (end_before_start, "window", InvalidInput, "end_at"),
    (start_in_the_past, "window", InvalidInput, "start_at"),
    (too_long, "window", InvalidInput, "end_at"),
    (out_of_service, "out_of_service", InvalidInput, "resources"),
    (robot_held_by_its_health_check, "out_of_service", InvalidInput, "resources"),
    (robot_without_experiment, "program", InvalidInput, "experiment"),
    (experiment_on_a_fixed_node, "program", InvalidInput, "experiment"),
    (two_robots, "program", InvalidInput, "resources"),
    (too_fast_for_this_robot, "program", InvalidInput, "experiment"),
    (program_longer_than_the_slot, "program", InvalidInput, "end_at"),
    (maintenance, "blackout", Conflict, "start_at"),
    (already_booked, "booked", Conflict, "start_at"),
    (over_quota, "quota", QuotaExceeded, "quota"),
]


@pytest.mark.parametrize(
    ("setup", "code", "error", "field"), CASES, ids=[c[0].__name__ for c in CASES]
)
def test_the_live_check_and_booking_agree(setup, code, error, field, owner):
    case = setup(owner)
    problems = booking_check(
        owner=owner,
        resources=case.resources,
        start_at=case.start_at,
        end_at=case.end_at,
        experiment=case.experiment,
        now=NOW,
    )
    before = Reservation.objects.count()
    if code is None:
        assert problems == []
        booking_create(
            owner=owner,
            resources=case.resources,
            start_at=case.start_at,
            end_at=case.end_at,
            experiment=case.experiment,
            now=NOW,
        )
        assert Reservation.objects.count() == before + 1
        return
    assert problems, "the live check found nothing wrong"
    first = problems[0]
    assert (first.code, first.field) == (code, field)
    with pytest.raises(error) as refused:
        booking_create(
            owner=owner,
            resources=case.resources,
            start_at=case.start_at,
            end_at=case.end_at,
            experiment=case.experiment,
            now=NOW,
        )
    assert type(refused.value) is error
    assert refused.value.message == first.message
    assert refused.value.fields.get(field), refused.value.fields
    assert Reservation.objects.count() == before  # a refusal changes nothing


def test_the_live_check_lists_every_problem_at_once(owner):
    node = FixedResourceFactory(enabled=False)
    Blackout.objects.create(start_at=START, end_at=END, reason="roof works", all_resources=True)
    QuotaPolicy.objects.create(name="short", max_length_s=600)
    problems = booking_check(
        owner=owner, resources=[node], start_at=START, end_at=END, experiment=None, now=NOW
    )
    assert [p.code for p in problems] == ["out_of_service", "blackout", "quota"]


def test_the_check_api_answers_problems_with_their_kind(owner, client_for):
    node = FixedResourceFactory(enabled=False)
    start = datetime.now(UTC) + timedelta(days=1)
    response = client_for(owner).post(
        "/api/v1/quota/check/",
        {
            "resources": [node.name],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(hours=1)).isoformat(),
        },
        format="json",
    )
    assert response.status_code == 200
    body = response.json()
    assert body["fits"] is False
    assert body["problems"] == [
        {
            "code": "out_of_service",
            "field": "resources",
            "message": f"{node.name} is out of service.",
        }
    ]
