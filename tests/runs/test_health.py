"""Robot health: a robot its agent reports unfit is taken out of booking, with the reason, and
only an admin puts it back.

The agent is the real application in-process (``tests/runs/conftest.py``); its e-stop is
latched through its API, its battery read from the simulated robot after real ticks.
"""

from __future__ import annotations

import time
from datetime import timedelta

import pytest
from django.core.cache import cache
from django.utils import timezone

from bookings.models import Resource
from bookings.selectors import resource_free_intervals
from bookings.services import resource_set_service
from core.audit.models import AuditEvent
from core.errors import InvalidInput, NotAllowed
from portal.runs.services.health import (
    robot_health_cached,
    robot_health_check,
    robot_health_problems,
)
from portal.runs.services.reservations import reservation_check, reservation_create
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db


@pytest.fixture
def robot(agent, mobile) -> Resource:
    mobile.agent_url = agent.url
    mobile.save()
    return mobile


def _book(owner, resource: Resource):
    start = timezone.now() + timedelta(hours=2)
    return reservation_create(
        owner=owner,
        resource=resource,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    )


def _held(resource: Resource) -> str:
    resource.refresh_from_db()
    return resource.hold_reason


def test_a_latched_estop_takes_the_robot_out_of_booking_with_the_reason(agent, robot, owner):
    agent.client.stop(user="carol", reason="someone on the roof")
    health = robot_health_check(resource_id=robot.pk)
    assert health is not None
    assert health.reachable
    reason = "emergency stop latched: someone on the roof (by carol)"
    assert health.problems == [reason]
    assert _held(robot) == reason
    with pytest.raises(InvalidInput) as refused:
        _book(owner, robot)
    assert refused.value.message == f"mobile-1 is out of service: {reason}."
    # The calendar's live check says the same; no free time is offered.
    start = timezone.now() + timedelta(hours=2)
    problems = reservation_check(
        owner=owner,
        resources=[robot],
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    ).problems
    assert [(p.code, p.message) for p in problems] == [("out_of_service", refused.value.message)]
    assert (
        resource_free_intervals(resource=robot, start_at=start, end_at=start + timedelta(1)) == []
    )
    [audit] = AuditEvent.objects.filter(action="resource.hold")
    assert (audit.actor_name, audit.target_id) == ("system", str(robot.pk))


def test_a_battery_under_the_threshold_takes_the_robot_out(agent, robot, settings):
    now_s = time.time()
    agent.run_clock(now_s - 2.0, now_s)  # real ticks: the filtered voltage is the robot's
    filtered_v = agent.client.status()["battery"]["filtered_v"]
    settings.HEALTH_LOW_BATTERY_V = filtered_v - 1
    robot_health_check(resource_id=robot.pk)
    assert _held(robot) == ""
    settings.HEALTH_LOW_BATTERY_V = filtered_v + 1
    robot_health_check(resource_id=robot.pk)
    assert _held(robot) == (
        f"battery low: {filtered_v:.1f} V, under {settings.HEALTH_LOW_BATTERY_V:g} V"
    )


def test_faults_and_the_agents_own_low_battery_flag_are_problems(agent):
    status = agent.client.status()
    assert robot_health_problems(status=status, low_battery_v=50) == []
    status["faults"] = ["robot not answering (no telemetry for 7 s)"]
    status["battery"] = {"filtered_v": None, "raw_v": None, "low_battery_v": 50.0, "low": True}
    assert robot_health_problems(status=status, low_battery_v=50) == [
        "fault: robot not answering (no telemetry for 7 s)",
        "battery low (the base station's own threshold)",
    ]


def test_an_agent_out_of_reach_for_longer_than_the_threshold_takes_the_robot_out(robot, settings):
    Resource.objects.filter(pk=robot.pk).update(agent_url="http://127.0.0.1:9")
    first_s = time.time()
    health = robot_health_check(resource_id=robot.pk, now_s=first_s)
    assert health is not None
    assert not health.reachable
    assert health.problems == []
    almost_s = first_s + settings.HEALTH_UNREACHABLE_S - 1
    robot_health_check(resource_id=robot.pk, now_s=almost_s)
    assert _held(robot) == ""
    robot_health_check(resource_id=robot.pk, now_s=first_s + settings.HEALTH_UNREACHABLE_S)
    assert _held(robot).startswith("base station unreachable since ")


def test_the_unreachable_count_survives_a_cache_restart(robot, settings):
    Resource.objects.filter(pk=robot.pk).update(agent_url="http://127.0.0.1:9")
    first_s = time.time()
    robot_health_check(resource_id=robot.pk, now_s=first_s)
    cache.clear()  # what a restarted Redis without persistence holds
    robot_health_check(resource_id=robot.pk, now_s=first_s + settings.HEALTH_UNREACHABLE_S - 1)
    assert _held(robot) == ""
    cache.clear()
    health = robot_health_check(resource_id=robot.pk, now_s=first_s + settings.HEALTH_UNREACHABLE_S)
    assert health is not None
    assert health.unreachable_since_s == pytest.approx(first_s, abs=1e-3)
    assert _held(robot).startswith("base station unreachable since ")


def test_a_robot_whose_agent_token_is_not_configured_is_held_once_with_the_reason(
    agent, robot, owner, caplog
):
    # A robot of an earlier start with two robots: its agent's token is not configured now.
    Resource.objects.filter(pk=robot.pk).update(agent_token_name="mobile-2")
    with caplog.at_level("WARNING", logger="portal.runs.services.health"):
        for _ in range(3):
            health = robot_health_check(resource_id=robot.pk)
    assert health is not None
    assert not health.reachable
    reason = (
        "agent not configured: names agent token 'mobile-2', which is not configured (AGENT_TOKENS)"
    )
    assert health.problems == [reason]
    assert _held(robot) == reason
    assert AuditEvent.objects.filter(action="resource.hold").count() == 1
    # Logged once, as the hold is made, and without a traceback.
    logged = [r for r in caplog.records if r.name == "portal.runs.services.health"]
    assert [r.getMessage() for r in logged] == [f"mobile-1 taken out of booking: {reason}"]
    assert all(r.exc_info is None for r in logged)
    with pytest.raises(InvalidInput) as refused:
        _book(owner, robot)
    assert refused.value.message == f"mobile-1 is out of service: {reason}."


def test_an_agent_that_answers_again_starts_the_count_afresh(agent, robot, settings):
    Resource.objects.filter(pk=robot.pk).update(agent_url="http://127.0.0.1:9")
    first_s = time.time()
    robot_health_check(resource_id=robot.pk, now_s=first_s)
    Resource.objects.filter(pk=robot.pk).update(agent_url=agent.url)
    back = robot_health_check(resource_id=robot.pk, now_s=first_s + 5)
    assert back is not None
    assert back.reachable
    assert back.unreachable_since_s is None
    robot.refresh_from_db()
    assert robot.agent_unreachable_since is None
    Resource.objects.filter(pk=robot.pk).update(agent_url="http://127.0.0.1:9")
    later_s = first_s + settings.HEALTH_UNREACHABLE_S + 1
    robot_health_check(resource_id=robot.pk, now_s=later_s)
    assert _held(robot) == ""


def test_the_last_reading_is_cached_for_the_pages(agent, robot):
    robot_health_check(resource_id=robot.pk)
    cached = robot_health_cached(name=robot.name)
    assert cached is not None
    assert cached.status is not None
    assert cached.status["resource"] == "mobile-1"
    assert cached.reachable
    assert cached.problems == []


def test_a_held_robot_stays_out_until_an_admin_puts_it_back_audited(
    agent, robot, owner, admin_user
):
    agent.client.stop(reason="check the rail")
    robot_health_check(resource_id=robot.pk)
    held = _held(robot)
    agent.client.release_stop()
    robot_health_check(resource_id=robot.pk)  # healthy again, but still held
    assert _held(robot) == held
    with pytest.raises(NotAllowed):
        resource_set_service(resource=robot, by=owner, enabled=True, reason="looks fine")
    resource_set_service(resource=robot, by=admin_user, enabled=True, reason="rail checked")
    assert _held(robot) == ""
    audit = AuditEvent.objects.get(action="resource.in_service")
    assert (audit.actor_name, audit.reason) == ("charlie", "rail checked")
    assert audit.data == {"lifted_hold": held}
    _book(owner, robot)  # bookable again


def test_a_robot_an_admin_took_out_of_service_is_watched_but_not_held(agent, robot, admin_user):
    resource_set_service(resource=robot, by=admin_user, enabled=False, reason="maintenance")
    agent.client.stop(reason="maintenance")
    health = robot_health_check(resource_id=robot.pk)
    assert health is not None
    assert health.problems == ["emergency stop latched: maintenance"]
    assert _held(robot) == ""  # out of service already; no hold, no mail
    assert not AuditEvent.objects.filter(action="resource.hold").exists()
