"""The admin robot console: every command reaches the real agent and the audit log."""

from __future__ import annotations

import json
import time
from datetime import UTC, timedelta

import pytest
import redis
from django.utils import timezone

from bookings.services import resource_hold
from core import live
from core.audit.models import AuditEvent
from tests.conftest import sign_in_with_second_factor

pytestmark = pytest.mark.django_db


@pytest.fixture
def robot(agent, mobile):
    mobile.agent_url = agent.url
    mobile.save()
    return mobile


def _tick(agent, seconds: float) -> None:
    now = time.time()
    agent.run_clock(now, now + seconds)


def test_an_admin_drives_by_hand_and_it_is_audited(robot, agent, admin_user, client_for):
    client = client_for(admin_user)
    response = client.post(
        "/api/v1/resources/mobile-1/robot/control/",
        {"velocity_mps": 0.4, "direction": "ccw", "ttl_s": 2, "reason": "check the north corner"},
        format="json",
        REMOTE_ADDR="192.0.2.5",
    )
    assert response.status_code == 200, response.content
    assert response.json()["manual"]["velocity_mps"] == 0.4
    _tick(agent, 0.5)
    status = client.get("/api/v1/resources/mobile-1/robot/").json()["status"]
    assert status["robot"]["commanded_velocity_mps"] > 0
    assert status["robot"]["commanded_direction"] == "ccw"
    event = AuditEvent.objects.get(action="robot.control")
    assert (event.actor_name, event.ip, event.reason) == (
        "charlie",
        "192.0.2.5",
        "check the north corner",
    )
    assert event.data["velocity_mps"] == 0.4


def test_a_drive_answers_and_streams_the_robots_motion(
    robot, agent, admin_user, client_for, settings
):
    """What the console beside its drive buttons shows, and every other console watching the
    robot: the base station's reading of the robot at each command."""
    pubsub = redis.Redis.from_url(settings.REDIS_URL).pubsub()
    pubsub.subscribe(live.redis_channel(live.robot_channel("mobile-1")))
    assert pubsub.get_message(timeout=5)["type"] == "subscribe"  # type: ignore[index]
    client = client_for(admin_user)
    body = {"velocity_mps": 0.4, "direction": "ccw", "ttl_s": 2, "reason": "north corner"}
    client.post("/api/v1/resources/mobile-1/robot/control/", body, format="json")
    _tick(agent, 0.5)
    response = client.post("/api/v1/resources/mobile-1/robot/control/", body, format="json")
    assert response.status_code == 200, response.content
    answer = response.json()
    assert answer["robot"]["velocity_mps"] > 0
    assert answer["robot"]["direction"] == "ccw"
    assert answer["link"]["state"] == "up"
    heard = []
    while len(heard) < 2:
        message = pubsub.get_message(ignore_subscribe_messages=True, timeout=5)
        assert message is not None, f"only {len(heard)} motion events heard"
        heard.append(json.loads(message["data"]))
    pubsub.close()
    assert [event["type"] for event in heard] == ["motion", "motion"]
    assert {k: heard[1][k] for k in ("clock", "robot", "link")} == {
        k: answer[k] for k in ("clock", "robot", "link")
    }
    assert heard[0]["clock"] < heard[1]["clock"]


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"velocity_mps": 0.4, "direction": "cw", "ttl_s": 1, "reason": ""}, "reason"),
        ({"velocity_mps": 9, "direction": "cw", "ttl_s": 1, "reason": "x"}, "velocity_mps"),
        ({"velocity_mps": 0.4, "direction": "cw", "ttl_s": 60, "reason": "x"}, "ttl_s"),
    ],
)
def test_bad_manual_commands_are_refused_before_reaching_the_robot(
    robot, admin_user, client_for, body, field
):
    response = client_for(admin_user).post(
        "/api/v1/resources/mobile-1/robot/control/", body, format="json"
    )
    assert response.status_code == 400
    assert field in response.json()["fields"]
    # The first problem is the detail: the console shows it as it is.
    assert response.json()["detail"].startswith(
        {"reason": "reason: Say why", "velocity_mps": "Velocity", "ttl_s": "ttl_s: "}[field]
    )
    assert not AuditEvent.objects.filter(action="robot.control").exists()


def test_the_emergency_stop_latches_until_released_with_a_reason(
    robot, agent, admin_user, client_for
):
    client = client_for(admin_user)
    assert (
        client.post("/api/v1/resources/mobile-1/robot/stop/", {}, format="json").status_code == 200
    )
    _tick(agent, 0.2)
    assert (
        client.get("/api/v1/resources/mobile-1/robot/").json()["status"]["estop"]["latched"] is True
    )
    refused = client.post(
        "/api/v1/resources/mobile-1/robot/control/",
        {"velocity_mps": 0.3, "direction": "cw", "ttl_s": 1, "reason": "try"},
        format="json",
    )
    assert refused.status_code == 409
    # In the portal's words: the agent's own name its API's path.
    assert refused.json()["detail"] == (
        "The base station refused: the emergency stop is latched: release it first (with a reason)"
    )
    assert AuditEvent.objects.get(action="robot.control").data["refused"]
    assert (
        client.post("/api/v1/resources/mobile-1/robot/release/", {}, format="json").status_code
        == 400
    )
    released = client.post(
        "/api/v1/resources/mobile-1/robot/release/", {"reason": "rail inspected"}, format="json"
    )
    assert released.status_code == 200
    assert released.json()["released"] is True
    # What was done to the robot, in order (the staff sign-in before it is audited too).
    done = AuditEvent.objects.filter(action__startswith="robot.").order_by("pk")
    assert list(done.values_list("action", flat=True)) == [
        "robot.stop",
        "robot.control",
        "robot.release",
    ]


def test_an_unreachable_base_station_is_a_clear_503_and_still_audited(
    mobile, admin_user, client_for, settings
):
    settings.AGENT_TOKENS = {"default": "x" * 32}
    mobile.agent_url = "http://127.0.0.1:9"
    mobile.save()
    response = client_for(admin_user).post(
        "/api/v1/resources/mobile-1/robot/stop/", {}, format="json"
    )
    assert response.status_code == 503
    assert "did not answer" in response.json()["detail"]
    assert AuditEvent.objects.get(action="robot.stop").data["failed"]


def test_the_daily_log_comes_from_the_base_station(robot, agent, admin_user, owner, client_for):
    from portal.runs.services import staging
    from portal.runs.services.reservations import reservation_create
    from tests.factories import ExperimentFactory

    start = timezone.now() + timedelta(minutes=1)
    reservation = reservation_create(
        owner=owner,
        resource=robot,
        start_at=start,
        end_at=start + timedelta(seconds=20),
        experiment=ExperimentFactory(owner=owner, title="log me"),
    )
    staging.run_stage(run_id=reservation.run.pk)
    agent.run_clock(start.timestamp(), start.timestamp() + 1)
    day = start.astimezone(UTC).date()
    log = client_for(admin_user).get(f"/api/v1/resources/mobile-1/robot/logs/{day.isoformat()}/")
    assert log.status_code == 200
    assert [e["title"] for e in log.json()["entries"]] == ["log me"]
    assert log.json()["entries"][0]["user"] == "alice"
    assert (
        client_for(admin_user).get("/api/v1/resources/mobile-1/robot/logs/yesterday/").status_code
        == 400
    )


def test_taking_the_robot_out_of_service_stops_bookings(
    robot, admin_user, owner, experiment, client_for
):
    from core.errors import InvalidInput
    from portal.runs.services.reservations import reservation_create

    client = client_for(admin_user)
    response = client.post(
        "/api/v1/resources/mobile-1/service/",
        {"enabled": False, "reason": "motor swap"},
        format="json",
    )
    assert response.status_code == 200
    assert response.json()["enabled"] is False
    start = timezone.now() + timedelta(hours=1)
    with pytest.raises(InvalidInput, match="out of service"):
        reservation_create(
            owner=owner,
            resource=robot,
            start_at=start,
            end_at=start + timedelta(hours=1),
            experiment=experiment,
        )
    assert AuditEvent.objects.get(action="resource.out_of_service").reason == "motor swap"


@pytest.mark.parametrize("who", ["anonymous", "owner", "other"])
def test_only_admins_reach_the_console(robot, who, owner, other, client_for, client):
    user = {"anonymous": None, "owner": owner, "other": other}[who]
    api = client_for(user)
    for method, url, body in [
        ("get", "/api/v1/resources/mobile-1/robot/", None),
        (
            "post",
            "/api/v1/resources/mobile-1/robot/control/",
            {"velocity_mps": 0.1, "direction": "cw", "reason": "x"},
        ),
        ("post", "/api/v1/resources/mobile-1/robot/stop/", {}),
        ("post", "/api/v1/resources/mobile-1/robot/release/", {"reason": "x"}),
        ("get", "/api/v1/resources/mobile-1/robot/logs/2026-01-01/", None),
        ("post", "/api/v1/resources/mobile-1/service/", {"enabled": False, "reason": "x"}),
    ]:
        kwargs = {"format": "json"} if method == "post" else {}
        expected = 401 if user is None else 403
        assert getattr(api, method)(url, body, **kwargs).status_code == expected, url
    if user is not None:
        client.force_login(user)
        assert client.get("/robot/mobile-1/").status_code == 403
    # Nothing done to the robot (the sign-in itself is audited).
    assert not AuditEvent.objects.exclude(action="account.sign_in").exists()


def test_the_console_page_is_served_to_admins(robot, admin_user, client):
    sign_in_with_second_factor(client, admin_user)
    page = client.get("/robot/mobile-1/")
    assert page.status_code == 200
    assert b"EMERGENCY STOP" in page.content
    # The staff menu names what the link opens, not only the robot.
    assert b'href="/robot/mobile-1/">Robot console (mobile-1)</a>' in page.content


def test_releasing_the_stop_says_whether_bookings_are_open_and_can_reopen_them(
    robot, agent, admin_user, client_for
):
    client = client_for(admin_user)
    url = "/api/v1/resources/mobile-1/robot"
    for reopen in (False, True):
        assert client.post(f"{url}/stop/", {}, format="json").status_code == 200
        _tick(agent, 0.2)
        # What the health check does when it sees the latch.
        resource_hold(resource_id=robot.pk, reason="emergency stop latched")
        released = client.post(
            f"{url}/release/", {"reason": "rail inspected", "reopen": reopen}, format="json"
        )
        assert released.status_code == 200, released.json()
        body = released.json()
        assert body["released"] is True
        assert (body["in_service"], body["hold_reason"]) == (
            (True, "") if reopen else (False, "emergency stop latched")
        )
        robot.refresh_from_db()
        assert robot.in_service is reopen
    # One reason, audited as both: the release and the return to service.
    rows = AuditEvent.objects.filter(action__in=["robot.release", "resource.in_service"])
    assert [(r.action, r.reason) for r in rows.order_by("pk")] == [
        ("robot.release", "rail inspected"),
        ("robot.release", "rail inspected"),
        ("resource.in_service", "rail inspected"),
    ]
    assert rows.get(action="resource.in_service").data["lifted_hold"] == "emergency stop latched"
