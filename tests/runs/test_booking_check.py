"""The calendar's live check and booking say the same thing about the same booking, and every
refusal to book, move, cancel or decide is a problem of ``bookings/rules.py`` with its code.

Each case sets up one reason to refuse (or none), asks the live check (or the rule), then tries
to book (or move, cancel, decide). The rule's first problem must be exactly what the service
raises (same kind, field and message), and "fits" must mean the booking is made. Every code of
``bookings.rules.PROBLEM_CODES`` is in a table here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest

from bookings.choices import ReservationState
from bookings.models import Blackout, QuotaPolicy, Reservation, Resource
from bookings.rules import (
    PROBLEM_CODES,
    Problem,
    ProgramRefused,
    QuotaExceeded,
    cancel_problems,
    decision_problems,
    move_problems,
)
from core.accounts.models import User
from core.errors import Conflict, DomainError, InvalidInput, NotAllowed
from portal.experiments.models import Experiment
from portal.runs.models import Run
from portal.runs.services.reservations import (
    reservation_cancel,
    reservation_check,
    reservation_create,
    reservation_decide,
    reservation_reschedule,
)
from portal.runs.states import RunState
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
    by: User | None = None  # who books (for the owner); default the owner
    override_reason: str = ""


def _program(owner, *velocities_mps: float, duration_s: float = 60.0) -> Experiment:
    # Stored as written: the point is what booking checks, not what experiment_create allows.
    return ExperimentFactory(
        owner=owner,
        segments=[
            {"velocity_mps": v, "direction": "cw", "duration_s": duration_s} for v in velocities_mps
        ],
    )


def no_resource(owner) -> Case:
    return Case([], None)


def a_resource_twice(owner) -> Case:
    node = FixedResourceFactory()
    return Case([node, node], None)


def for_someone_else_by_a_user(owner) -> Case:
    return Case([FixedResourceFactory()], None, by=UserFactory(username="mallory"))


def a_quota_override_by_a_user(owner) -> Case:
    return Case([FixedResourceFactory()], None, override_reason="I need it")


def someone_elses_experiment(owner) -> Case:
    return Case([MobileResourceFactory()], _program(UserFactory(username="zoe"), 1.0))


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


def too_fast_for_this_robots_base_station(owner) -> Case:
    # The portal allows 2.0 m/s; the robot's agent reported 1.5 m/s: the stricter decides.
    robot = MobileResourceFactory(agent_max_velocity_mps=1.5)
    return Case([robot], _program(owner, 1.0, 1.8))


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
    reservation_create(
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
    (no_resource, "resources", InvalidInput, "resources"),
    (a_resource_twice, "resources", InvalidInput, "resources"),
    (for_someone_else_by_a_user, "permission", NotAllowed, ""),
    (a_quota_override_by_a_user, "permission", NotAllowed, "override_reason"),
    (someone_elses_experiment, "permission", NotAllowed, "experiment"),
    (fits_on_a_fixed_node, None, None, ""),
    (fits_on_the_robot, None, None, ""),
    (end_before_start, "window", InvalidInput, "end_at"),
    (start_in_the_past, "window", InvalidInput, "start_at"),
    (too_long, "window", InvalidInput, "end_at"),
    (out_of_service, "out_of_service", InvalidInput, "resources"),
    (robot_held_by_its_health_check, "out_of_service", InvalidInput, "resources"),
    (robot_without_experiment, "program", ProgramRefused, "experiment"),
    (experiment_on_a_fixed_node, "program", ProgramRefused, "experiment"),
    (two_robots, "program", ProgramRefused, "resources"),
    (too_fast_for_this_robot, "program", ProgramRefused, "experiment"),
    (too_fast_for_this_robots_base_station, "program", ProgramRefused, "experiment"),
    (program_longer_than_the_slot, "program", ProgramRefused, "end_at"),
    (maintenance, "blackout", Conflict, "start_at"),
    (already_booked, "booked", Conflict, "start_at"),
    (over_quota, "quota", QuotaExceeded, "quota"),
]


@pytest.mark.parametrize(
    ("setup", "code", "error", "field"), CASES, ids=[c[0].__name__ for c in CASES]
)
def test_the_live_check_and_booking_agree(setup, code, error, field, owner):
    case = setup(owner)
    asked = {
        "owner": owner,
        "resources": case.resources,
        "start_at": case.start_at,
        "end_at": case.end_at,
        "experiment": case.experiment,
        "by": case.by,
        "override_reason": case.override_reason,
        "now": NOW,
    }
    check = reservation_check(**asked)
    problems = check.problems
    before = Reservation.objects.count()
    if code is None:
        assert problems == []
        assert check.fits
        reservation_create(**asked)
        assert Reservation.objects.count() == before + 1
        return
    assert problems, "the live check found nothing wrong"
    assert not check.fits
    first = problems[0]
    assert (first.code, first.field) == (code, field)
    with pytest.raises(error) as refused:
        reservation_create(**asked)
    assert type(refused.value) is error
    assert refused.value.message == first.message
    if field:
        assert refused.value.fields.get(field), refused.value.fields
    else:
        assert refused.value.fields == {}
    assert Reservation.objects.count() == before  # a refusal changes nothing


def test_a_program_is_refused_at_booking_by_the_agents_stricter_limit_naming_it(owner):
    robot = MobileResourceFactory(max_velocity_mps=2.0, agent_max_velocity_mps=1.5)
    with pytest.raises(InvalidInput) as refused:
        reservation_create(
            owner=owner,
            resources=[robot],
            start_at=START,
            end_at=END,
            experiment=_program(owner, 1.8),
            now=NOW,
        )
    assert refused.value.message == (
        "Segment 0: velocity 1.8 m/s exceeds the maximum of mobile-1: "
        "1.5 m/s, the limit its base station reports."
    )


def test_the_portals_stricter_limit_is_named_when_it_decides(owner):
    robot = MobileResourceFactory(max_velocity_mps=1.2, agent_max_velocity_mps=1.5)
    problems = reservation_check(
        owner=owner,
        resources=[robot],
        start_at=START,
        end_at=END,
        experiment=_program(owner, 1.3),
        now=NOW,
    ).problems
    assert [p.message for p in problems] == [
        "Segment 0: velocity 1.3 m/s exceeds the maximum of mobile-1: "
        "1.2 m/s, the portal's limit for it."
    ]


def test_the_live_check_lists_every_problem_at_once(owner):
    node = FixedResourceFactory(enabled=False)
    Blackout.objects.create(start_at=START, end_at=END, reason="roof works", all_resources=True)
    QuotaPolicy.objects.create(name="short", max_length_s=600)
    check = reservation_check(
        owner=owner, resources=[node], start_at=START, end_at=END, experiment=None, now=NOW
    )
    assert [p.code for p in check.problems] == ["out_of_service", "blackout", "quota"]
    assert check.leases_from is None  # no scheduler is configured: nothing asked of it


def _check_answer(client, path: str, node: Resource):
    start = datetime.now(UTC) + timedelta(days=1)
    return client.post(
        path,
        {
            "resources": [node.name],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(hours=1)).isoformat(),
        },
        format="json",
    )


def test_the_check_api_answers_problems_with_their_kind(owner, client_for):
    node = FixedResourceFactory(enabled=False)
    response = _check_answer(client_for(owner), "/api/v1/reservations/check/", node)
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
    assert (body["leases_from"], body["notice"], body["needs_approval"]) == (None, "", False)
    assert "Deprecation" not in response


def test_the_deprecated_check_path_still_answers_the_same_and_says_it_is_deprecated(
    owner, client_for
):
    node = FixedResourceFactory(enabled=False)
    client = client_for(owner)
    old = _check_answer(client, "/api/v1/quota/check/", node)
    new = _check_answer(client, "/api/v1/reservations/check/", node)
    assert old.status_code == 200
    assert old.json() == new.json()
    assert old["Deprecation"] == "true"
    assert old["Link"] == '</api/v1/reservations/check/>; rel="successor-version"'
    schema = client.get("/api/schema/", HTTP_ACCEPT="application/json").json()
    assert schema["paths"]["/api/v1/quota/check/"]["post"]["deprecated"] is True
    assert "deprecated" not in schema["paths"]["/api/v1/reservations/check/"]["post"]


def test_a_booking_that_needs_approval_says_so_and_waits_unless_an_admin_books(owner, admin_user):
    node = FixedResourceFactory(requires_approval=True)
    check = reservation_check(
        owner=owner, resources=[node], start_at=START, end_at=END, experiment=None, now=NOW
    )
    assert check.fits
    assert check.needs_approval
    booked = reservation_create(owner=owner, resource=node, start_at=START, end_at=END, now=NOW)
    assert booked.state == ReservationState.REQUESTED
    by_admin = reservation_check(
        owner=owner,
        by=admin_user,
        resources=[node],
        start_at=END,
        end_at=END + timedelta(minutes=30),
        experiment=None,
        now=NOW,
    )
    assert by_admin.fits
    assert not by_admin.needs_approval
    booked = reservation_create(
        owner=owner,
        by=admin_user,
        resource=node,
        start_at=END,
        end_at=END + timedelta(minutes=30),
        now=NOW,
    )
    assert booked.state == ReservationState.CONFIRMED


# --- Moving, cancelling, deciding: each refusal is the rule's first problem ------------------


@dataclass
class Change:
    """A booking, who acts on it, and the rule and service that judge the action."""

    reservation: Reservation
    by: User
    rule: Callable[[], list[Problem]]
    act: Callable[[], object]


def _booked(owner, *, robot: bool = False, **extra) -> Reservation:
    if robot:
        return reservation_create(
            owner=owner,
            resource=MobileResourceFactory(),
            experiment=_program(owner, 1.0),
            start_at=START,
            end_at=END,
            now=NOW,
            **extra,
        )
    return reservation_create(
        owner=owner, resource=FixedResourceFactory(), start_at=START, end_at=END, now=NOW, **extra
    )


def _move(reservation: Reservation, by: User, *, now: datetime = NOW, run_started=False):
    later = (START + timedelta(hours=1), END + timedelta(hours=1))
    return Change(
        reservation,
        by,
        lambda: move_problems(reservation=reservation, by=by, now=now, run_started=run_started),
        lambda: reservation_reschedule(
            reservation=reservation, by=by, start_at=later[0], end_at=later[1], now=now
        ),
    )


def _cancel(reservation: Reservation, by: User, reason: str = "") -> Change:
    return Change(
        reservation,
        by,
        lambda: cancel_problems(reservation=reservation, by=by, reason=reason),
        lambda: reservation_cancel(reservation=reservation, by=by, reason=reason),
    )


def _decide(reservation: Reservation, by: User, *, approve: bool, reason: str = "") -> Change:
    return Change(
        reservation,
        by,
        lambda: decision_problems(reservation=reservation, by=by, approve=approve, reason=reason),
        lambda: reservation_decide(reservation=reservation, by=by, approve=approve, reason=reason),
    )


def move_someone_elses(owner, admin) -> Change:
    return _move(_booked(owner), UserFactory(username="mallory"))


def move_once_its_run_is_staged(owner, admin) -> Change:
    reservation = _booked(owner, robot=True)
    Run.objects.filter(reservation=reservation).update(state=RunState.STAGED)
    return _move(reservation, owner, run_started=True)


def move_once_it_began(owner, admin) -> Change:
    return _move(_booked(owner), owner, now=START + timedelta(minutes=1))


def move_a_cancelled_one(owner, admin) -> Change:
    reservation = _booked(owner)
    reservation_cancel(reservation=reservation, by=owner)
    reservation.refresh_from_db()
    return _move(reservation, owner)


def cancel_someone_elses(owner, admin) -> Change:
    return _cancel(_booked(owner), UserFactory(username="mallory"))


def cancel_twice(owner, admin) -> Change:
    reservation = _booked(owner)
    reservation_cancel(reservation=reservation, by=owner)
    reservation.refresh_from_db()
    return _cancel(reservation, owner)


def cancel_someone_elses_without_saying_why(owner, admin) -> Change:
    return _cancel(_booked(owner), admin)


def decide_as_a_user(owner, admin) -> Change:
    node = FixedResourceFactory(requires_approval=True)
    reservation = reservation_create(
        owner=owner, resource=node, start_at=START, end_at=END, now=NOW
    )
    return _decide(reservation, owner, approve=True)


def reject_without_saying_why(owner, admin) -> Change:
    node = FixedResourceFactory(requires_approval=True)
    reservation = reservation_create(
        owner=owner, resource=node, start_at=START, end_at=END, now=NOW
    )
    return _decide(reservation, admin, approve=False)


def approve_a_confirmed_one(owner, admin) -> Change:
    return _decide(_booked(owner), admin, approve=True)


CHANGES: list[tuple[Callable[[Any, Any], Change], str, type[DomainError], str]] = [
    # (setup, problem code, error the service raises, field)
    (move_someone_elses, "permission", NotAllowed, ""),
    (move_once_its_run_is_staged, "state", Conflict, ""),
    (move_once_it_began, "state", Conflict, ""),
    (move_a_cancelled_one, "state", Conflict, ""),
    (cancel_someone_elses, "permission", NotAllowed, ""),
    (cancel_twice, "state", Conflict, ""),
    (cancel_someone_elses_without_saying_why, "reason", InvalidInput, "reason"),
    (decide_as_a_user, "permission", NotAllowed, ""),
    (reject_without_saying_why, "reason", InvalidInput, "reason"),
    (approve_a_confirmed_one, "state", Conflict, ""),
]


@pytest.mark.parametrize(
    ("setup", "code", "error", "field"), CHANGES, ids=[c[0].__name__ for c in CHANGES]
)
def test_each_refused_change_is_the_rules_first_problem(
    setup, code, error, field, owner, admin_user
):
    change = setup(owner, admin_user)
    problems = change.rule()
    assert problems, "the rule found nothing wrong"
    first = problems[0]
    assert (first.code, first.field) == (code, field)
    before = Reservation.objects.values_list("state", "start_at").get(pk=change.reservation.pk)
    with pytest.raises(error) as refused:
        change.act()
    assert type(refused.value) is error
    assert refused.value.message == first.message
    assert refused.value.fields == ({field: [first.message]} if field else {})
    after = Reservation.objects.values_list("state", "start_at").get(pk=change.reservation.pk)
    assert after == before  # a refusal changes nothing


def test_every_problem_code_has_a_case_here():
    tested = {c[1] for c in CASES} | {c[1] for c in CHANGES}
    # "lease" needs the testbed scheduler: tests/bookings/scheduler/test_booking_flow.py.
    assert set(PROBLEM_CODES) - tested == {"lease"}
