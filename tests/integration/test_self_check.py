"""The self-check end to end with real processes: two robots, each behind its own agent, each
healthy or worn as the simulator can wear (``AGENT_SIM_CONFIG`` for its agent alone). Both
checks are booked through the one door, staged, driven, collected and judged by the workers
as any run: a healthy robot passes and its check becomes its baseline; a worn one is held
with the reason its wear gives, and the staff are told (``robot.held``)."""

from __future__ import annotations

import time
from datetime import timedelta

import pytest
from django.utils import timezone

from bookings.models import Resource
from core.events.models import Event
from portal.runs.models import SelfCheck, SelfCheckBaseline
from portal.runs.self_check import RULES
from portal.runs.services.self_check import HOLD_PREFIX, self_check_book
from tests.conftest import staff_verified
from tests.factories import MobileResourceFactory, UserFactory
from tests.integration.stack import running_stack
from tests.runs.rehearsals import WEARS

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

# The lap of a check in a test: 10 m, not the rail's 120 (the checks run in real time).
LAP_M = 10
# Each wear as a simulator file: the values of tests/runs/rehearsals.py, where the figures
# they give are shown in simulated time.
WEAR_FILES = {
    "wheel slip": "[physics]\nwheel_slip = 0.15\n",
    "motor lag": "[physics]\nthrottle_time_constant_s = 0.6\n",
    "worn battery": "[battery]\ninternal_resistance_ohm = 1.5\n",
    "no RTK fix": '[gps]\nfix = "rtk_float"\n',
}
# Two robots a system; None: healthy. One system: each costs a worker about 100 s and the
# two real-time robots a third of the machine's two cores meanwhile. Every wear of WEAR_FILES
# ran here as the pairs ("wheel slip", "motor lag") and ("no RTK fix", None) too, each held
# with its reason (254 s for the three); the suite keeps one, and each wear's figure through
# the agent's own code in simulated time (tests/runs/test_self_check.py).
PAIRS = [("worn battery", None)]
ROBOTS = (("mobile-1", "agent"), ("mobile-2", "agent-2"))


@pytest.mark.parametrize(("first", "second"), PAIRS, ids=lambda wear: wear or "healthy")
def test_a_healthy_robot_passes_and_a_worn_one_is_held_with_its_wears_reason(
    tmp_path, settings, first, second
):
    assert set(WEAR_FILES) == set(WEARS)
    settings.SELF_CHECK_LAP_M = LAP_M
    wears = dict(zip((name for name, _ in ROBOTS), (first, second), strict=True))
    process_env = {}
    for (name, agent), wear in zip(ROBOTS, (first, second), strict=True):
        if wear is not None:
            config = tmp_path / f"{name}.toml"
            config.write_text(WEAR_FILES[wear])
            process_env[agent] = {"AGENT_SIM_CONFIG": str(config)}
    with running_stack(
        tmp_path / "var",
        broker_url=settings.CELERY_BROKER_URL,
        second_robot=True,
        process_env=process_env,
    ) as stack:
        judged = _both_checked(stack)
        logs = "\n".join(p.output() for p in stack["procs"])
    states = {n: (c.state, c.run.state, c.problems, c.reason) for n, c in judged.items()}
    for name, wear in wears.items():
        check = judged[name]
        print(f"{name} ({wear or 'healthy'}): {check.state} {check.figures}")
        robot = Resource.objects.get(name=name)
        if wear is None:
            assert check.state == SelfCheck.State.PASSED, f"{states}\n{logs}"
            assert SelfCheckBaseline.objects.get(resource=robot).source_id == check.pk
            assert robot.hold_reason == ""
            continue
        assert check.state == SelfCheck.State.FAILED, f"{states}\n{logs}"
        label = RULES[WEARS[wear][1]].label
        assert check.problems[0].startswith(label), check.problems
        assert robot.hold_reason.startswith(HOLD_PREFIX + label), robot.hold_reason
        assert Event.objects.filter(type="robot.held", payload__resource=name).count() == 1
        assert not SelfCheckBaseline.objects.filter(resource=robot).exists()


def _both_checked(stack) -> dict[str, SelfCheck]:
    """Both robots' checks booked together, waited for until judged; by robot."""
    limits = {"max_velocity_mps": 1.0, "max_accel_mps2": 0.5}
    robots = [
        MobileResourceFactory(name="mobile-1", agent_url=stack.agent_url, **limits),
        MobileResourceFactory(
            name="mobile-2", agent_url=stack.agent2_url, agent_token_name="mobile-2", **limits
        ),
    ]
    admin = staff_verified(UserFactory(username="ada", is_staff=True, is_superuser=True))
    start = timezone.now() + timedelta(seconds=8)
    checks = [self_check_book(resource=r, by=admin, start_at=start) for r in robots]
    program_s = sum(s["duration_s"] for s in checks[0].run.segments)
    deadline = time.monotonic() + program_s + 120
    while time.monotonic() < deadline:
        if not SelfCheck.objects.filter(state=SelfCheck.State.PENDING).exists():
            break
        time.sleep(0.5)
    return {c.resource.name: c for c in SelfCheck.objects.select_related("resource", "run")}
