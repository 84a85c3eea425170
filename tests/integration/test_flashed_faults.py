"""Fault tests of ``test_faults.py`` again, with the flashed image as both robots' firmware.

``AGENT_ROBOT=sim-flashed``: each agent's robot runs ``robot.elf``, the image ``make
firmware`` builds, on an emulated ATmega328P (basestation/sim/flashed.py), reached over the
same emulated air as the host-built core. The tests are ``test_faults.py``'s own, imported so
that pytest runs them here on this module's ``fault_stack``: the e-stop latched by the image
itself (its EEPROM) takes the robot out of booking, and two robots, each its own emulated chip,
run at once with their own data.
"""

from __future__ import annotations

import pytest

from bookings.models import Resource
from tests.factories import MobileResourceFactory
from tests.integration.stack import FAULT_ENV, private_stack
from tests.integration.test_faults import (
    test_an_estop_report_takes_the_robot_out_of_booking,
    test_two_robots_run_at_the_same_time_each_with_its_own_data,
)

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

__all__ = [
    "test_an_estop_report_takes_the_robot_out_of_booking",
    "test_two_robots_run_at_the_same_time_each_with_its_own_data",
]


@pytest.fixture(scope="module")
def fault_stack(tmp_path_factory, django_db_setup):
    """``fault_stack`` (tests/integration/stack.py) with both robots on the flashed image."""
    with private_stack(
        tmp_path_factory.mktemp("flashed-fault-stack"),
        second_robot=True,
        extra_env={**FAULT_ENV, "AGENT_ROBOT": "sim-flashed"},
    ) as running:
        yield running


@pytest.fixture
def robots(fault_stack) -> tuple[Resource, Resource]:
    first = MobileResourceFactory(agent_url=fault_stack.agent_url)
    second = MobileResourceFactory(
        name="mobile-2", agent_url=fault_stack.agent2_url, agent_token_name="mobile-2"
    )
    return first, second


def test_both_agents_drive_the_flashed_image(fault_stack):
    """What the fault tests above ran against: each agent started its robot on the image."""
    agents = [proc for name, proc in fault_stack.procs.items() if name.startswith("agent")]
    assert len(agents) == 2, sorted(fault_stack.procs)
    for agent in agents:
        started = [line for line in agent.lines if "flashed image" in line]
        assert started, agent.output()
        assert "robot.elf on an emulated ATmega328P" in started[0]
