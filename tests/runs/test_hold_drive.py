"""Hold-to-drive over the API: each held command reaches the agent, but its repeats are one
audited action; a change of velocity or direction, a pause, or a refusal is audited anew."""

from __future__ import annotations

import pytest
from django.core.cache import cache

from core.audit.models import AuditEvent

pytestmark = pytest.mark.django_db

URL = "/api/v1/resources/mobile-1/robot/control/"


@pytest.fixture
def robot(agent, mobile):
    mobile.agent_url = agent.url
    mobile.save()
    return mobile


def _hold(client, velocity_mps: float, direction: str = "cw", **extra) -> dict:
    body = {
        "velocity_mps": velocity_mps,
        "direction": direction,
        "ttl_s": 0.6,
        "reason": "to the north corner",
        "hold": True,
        **extra,
    }
    response = client.post(URL, body, format="json")
    assert response.status_code == 200, response.content
    return response.json()


def _audited() -> list[tuple[float, str]]:
    return [
        (data["velocity_mps"], data["direction"])
        for data in AuditEvent.objects.filter(action="robot.control")
        .order_by("pk")
        .values_list("data", flat=True)
    ]


def test_the_repeats_of_a_hold_reach_the_agent_and_are_audited_once(
    robot, agent, admin_user, client_for
):
    client = client_for(admin_user)
    for _ in range(5):
        assert _hold(client, 0.4)["manual"]["velocity_mps"] == 0.4
    assert _audited() == [(0.4, "cw")]
    _hold(client, 0.4, "ccw")
    _hold(client, 0.0, "ccw")
    _hold(client, 0.0, "ccw")
    assert _audited() == [(0.4, "cw"), (0.4, "ccw"), (0.0, "ccw")]
    # A pause longer than the audit gap: the next hold is a new action.
    cache.clear()
    _hold(client, 0.0, "ccw")
    assert len(_audited()) == 4


def test_commands_without_hold_are_audited_each_time(robot, admin_user, client_for):
    client = client_for(admin_user)
    for _ in range(2):
        response = client.post(
            URL,
            {"velocity_mps": 0.3, "direction": "cw", "ttl_s": 1, "reason": "check"},
            format="json",
        )
        assert response.status_code == 200
    assert _audited() == [(0.3, "cw"), (0.3, "cw")]
    assert all("hold" not in d for d in AuditEvent.objects.values_list("data", flat=True))


def test_a_refused_held_command_is_audited_every_time(robot, agent, admin_user, client_for):
    client = client_for(admin_user)
    agent.client.stop(user="carol", reason="someone on the roof")
    for _ in range(2):
        response = client.post(
            URL,
            {"velocity_mps": 0.3, "direction": "cw", "ttl_s": 0.6, "reason": "x", "hold": True},
            format="json",
        )
        assert response.status_code == 409
    refused = AuditEvent.objects.filter(action="robot.control", data__has_key="refused")
    assert refused.count() == 2


def test_only_admins_hold_to_drive(robot, owner, client_for):
    response = client_for(owner).post(
        URL,
        {"velocity_mps": 0.3, "direction": "cw", "ttl_s": 0.6, "reason": "x", "hold": True},
        format="json",
    )
    assert response.status_code == 403
    assert client_for(None).post(URL, {}, format="json").status_code in (401, 403)
    assert not AuditEvent.objects.filter(action="robot.control").exists()
