"""Velocity limits end to end: simulated firmware → agent → portal, each layer only stricter.

The agent is the real application behind a real HTTP server, driving the simulated robot (the
firmware core through ctypes on an emulated radio). Its firmware is compiled with a 4 m/s hard
maximum; the agent is configured at 1.5 m/s; the portal's resource allows 2.0 m/s. A program
the portal accepts at booking is then never refused at staging.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from datetime import timedelta

import pytest
from django.utils import timezone
from werkzeug.serving import make_server

from basestation.app import create_app
from basestation.client import AgentClient
from basestation.config import AgentConfig
from basestation.runtime import get_runtime
from bookings.admin import ResourceForm
from bookings.models import Resource
from core.errors import InvalidInput
from portal.runs.models import Run
from portal.runs.services import staging
from portal.runs.services.health import robot_health_check
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.conftest import sign_in_with_second_factor
from tests.factories import ExperimentFactory

pytestmark = pytest.mark.django_db

TOKEN = "limits-test-token"
AGENT_LIMIT_MPS = 1.5
FIRMWARE_HARD_MAX_MPS = 4.0  # AMZ_HARD_MAX_VELOCITY_MM_S in firmware/core/robot_config.h


@pytest.fixture
def agent_url(tmp_path, settings) -> Iterator[str]:
    config = AgentConfig(
        token=TOKEN,
        data_dir=tmp_path / "agent",
        robot="sim",
        max_velocity_mps=AGENT_LIMIT_MPS,
    )
    app = create_app(config, start_control_loop=False)
    server = make_server("127.0.0.1", 0, app, threaded=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    settings.AGENT_TOKENS = {"default": TOKEN}
    try:
        yield f"http://127.0.0.1:{server.server_port}"
    finally:
        server.shutdown()
        thread.join()
        server.server_close()
        get_runtime(app).close()


@pytest.fixture
def robot(agent_url, mobile) -> Resource:
    mobile.agent_url = agent_url
    mobile.max_velocity_mps = 2.0
    mobile.save()
    return mobile


def _book(owner, robot: Resource, velocity_mps: float):
    start = timezone.now() + timedelta(hours=2)
    return reservation_create(
        owner=owner,
        resource=robot,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(
            owner=owner,
            segments=[{"velocity_mps": velocity_mps, "direction": "cw", "duration_s": 5.0}],
        ),
    )


def test_the_agent_reports_its_effective_limits_and_the_firmwares_hard_maximum(agent_url):
    with AgentClient(agent_url, TOKEN) as client:
        limits = client.status()["limits"]
    assert limits == {
        "max_velocity_mps": AGENT_LIMIT_MPS,
        "max_accel_mps2": 1.0,
        "robot_hard_max_velocity_mps": FIRMWARE_HARD_MAX_MPS,
        "robot_confirmed": True,
    }


def test_the_health_sweep_records_what_the_agent_reports(robot):
    robot_health_check(resource_id=robot.pk)
    robot.refresh_from_db()
    assert (
        robot.agent_max_velocity_mps,
        robot.agent_max_accel_mps2,
        robot.robot_hard_max_velocity_mps,
    ) == (AGENT_LIMIT_MPS, 1.0, FIRMWARE_HARD_MAX_MPS)
    assert robot.agent_limits_at is not None
    assert robot.agent_is_stricter
    recorded_at = robot.agent_limits_at
    robot_health_check(resource_id=robot.pk)  # nothing changed: nothing written
    robot.refresh_from_db()
    assert robot.agent_limits_at == recorded_at


def test_portal_2_agent_1_5_program_1_8_is_refused_at_booking_naming_the_agents_limit(robot, owner):
    robot_health_check(resource_id=robot.pk)
    with pytest.raises(InvalidInput) as refused:
        _book(owner, robot, 1.8)
    assert refused.value.message == (
        "Segment 0: velocity 1.8 m/s exceeds the maximum of mobile-1: "
        "1.5 m/s, the limit its base station reports."
    )
    assert not Run.objects.exists()


def test_a_program_the_portal_accepted_is_staged_with_the_agents_limits(robot, owner):
    robot_health_check(resource_id=robot.pk)
    run = Run.objects.get(reservation=_book(owner, robot, 1.5))
    assert staging.run_agent_body(run)["limits"] == {"max_velocity_mps": 1.5, "max_accel_mps2": 1.0}
    staging.run_stage(run_id=run.pk)
    run.refresh_from_db()
    assert run.state == RunState.STAGED, run.reason


def test_a_resource_limit_looser_than_the_agents_cannot_be_saved(robot):
    robot_health_check(resource_id=robot.pk)
    robot.refresh_from_db()
    data = {
        "name": robot.name,
        "kind": robot.kind,
        "agent_url": robot.agent_url,
        "agent_token_name": "default",
        "max_accel_mps2": 1.0,
        "enabled": True,
        "hold_reason": "",
    }
    looser = ResourceForm(data={**data, "max_velocity_mps": 2.0}, instance=robot)
    assert not looser.is_valid()
    assert looser.errors["max_velocity_mps"] == [
        "2 m/s is above the 1.5 m/s that mobile-1's base station allows "
        "(AGENT_MAX_VELOCITY_MPS): set at most 1.5 m/s, or raise the base station's limit first."
    ]
    matching = ResourceForm(data={**data, "max_velocity_mps": 1.5}, instance=robot)
    assert matching.is_valid(), matching.errors
    matching.save()
    robot.refresh_from_db()
    assert not robot.agent_is_stricter


def test_a_stricter_agent_shows_on_the_console_and_the_admins_resource_page(
    robot, admin_user, client
):
    sign_in_with_second_factor(client, admin_user)
    warning = "Its base station allows at most 1.5 m/s"
    assert warning not in client.get(f"/robot/{robot.name}/").content.decode()
    robot_health_check(resource_id=robot.pk)
    console = client.get(f"/robot/{robot.name}/").content.decode()
    assert warning in console
    assert 'data-max="1.5"' in console  # manual drive is held to the same limit
    admin_page = client.get(f"/admin/bookings/resource/{robot.pk}/change/").content.decode()
    assert "Its base station allows only 1.5 m/s, below this resource&#x27;s 2 m/s" in admin_page
