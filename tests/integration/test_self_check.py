"""The self-check end to end with real processes: two robots, each behind its own agent, one
healthy and one whose battery has worn (its internal resistance ten times the new one's).
Both checks are booked through the one door, staged, driven, collected and judged by the
workers as any run: the healthy robot passes and its check becomes its baseline, the worn one
is held with the reason, and the staff are told (``robot.held``)."""

from __future__ import annotations

import time
from datetime import timedelta

import pytest
from django.conf import settings
from django.utils import timezone

from bookings.models import Resource
from core.events.models import Event
from portal.runs.models import SelfCheck, SelfCheckBaseline
from portal.runs.services.self_check import HOLD_PREFIX, self_check_book
from tests.conftest import staff_verified
from tests.factories import MobileResourceFactory, UserFactory
from tests.integration.stack import running_stack

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

# The lap of a check in a test: 20 m, not the rail's 120 (the checks run in real time).
LAP_M = 20
# A battery string of 1.5 Ω instead of 0.12 Ω: it sags about 0.9 V while the robot
# accelerates (tests/runs/test_self_check.py shows the figure in simulated time).
WORN_BATTERY = "[battery]\ninternal_resistance_ohm = 1.5\n"


@pytest.fixture
def two_robots(tmp_path):
    worn = tmp_path / "worn-battery.toml"
    worn.write_text(WORN_BATTERY)
    with running_stack(
        tmp_path / "var",
        broker_url=settings.CELERY_BROKER_URL,
        second_robot=True,
        process_env={"agent": {"AGENT_SIM_CONFIG": str(worn)}},
    ) as running:
        yield running


def test_the_healthy_robot_passes_and_the_worn_one_is_held_with_the_reason(two_robots, settings):
    stack = two_robots
    settings.SELF_CHECK_LAP_M = LAP_M
    limits = {"max_velocity_mps": 1.0, "max_accel_mps2": 0.5}
    worn = MobileResourceFactory(name="mobile-1", agent_url=stack.agent_url, **limits)
    healthy = MobileResourceFactory(
        name="mobile-2", agent_url=stack.agent2_url, agent_token_name="mobile-2", **limits
    )
    admin = staff_verified(UserFactory(username="ada", is_staff=True, is_superuser=True))
    start = timezone.now() + timedelta(seconds=8)
    checks = {
        r.name: self_check_book(resource=r, by=admin, start_at=start) for r in (worn, healthy)
    }
    program_s = sum(s["duration_s"] for s in checks["mobile-1"].run.segments)

    deadline = time.monotonic() + program_s + 120
    while time.monotonic() < deadline:
        pending = SelfCheck.objects.filter(state=SelfCheck.State.PENDING).count()
        if not pending:
            break
        time.sleep(0.5)
    judged = {c.resource.name: c for c in SelfCheck.objects.select_related("resource", "run")}
    logs = "\n".join(p.output() for p in stack["procs"])
    states = {name: (c.state, c.run.state, c.problems, c.reason) for name, c in judged.items()}
    for name, check in judged.items():
        print(f"{name}: {check.state} {check.figures}")
    assert judged["mobile-2"].state == SelfCheck.State.PASSED, f"{states}\n{logs}"
    assert judged["mobile-1"].state == SelfCheck.State.FAILED, f"{states}\n{logs}"

    # The healthy robot's check is its baseline, and it stays in booking.
    assert SelfCheckBaseline.objects.get(resource=healthy).source_id == judged["mobile-2"].pk
    assert Resource.objects.get(pk=healthy.pk).hold_reason == ""
    assert judged["mobile-2"].figures["rtk_share"] == 1.0
    # The worn one: only its battery, held with that reason, and the staff told.
    problems = judged["mobile-1"].problems
    assert len(problems) == 1, problems
    assert problems[0].startswith("battery sag under load"), problems
    hold = Resource.objects.get(pk=worn.pk).hold_reason
    assert hold.startswith(HOLD_PREFIX + "battery sag under load"), hold
    told = Event.objects.get(type="robot.held")
    assert told.payload["resource"] == "mobile-1"
    assert not SelfCheckBaseline.objects.filter(resource=worn).exists()
