"""``/metrics``: the system's state and the HTTP metrics for Prometheus, behind a token."""

from __future__ import annotations

import time

import pytest
from django.core.cache import cache
from prometheus_client.parser import text_string_to_metric_families

from bookings.models import Resource
from portal.runs.models import Run
from portal.runs.services.health import RobotHealth, _cache_key
from portal.runs.states import RunState
from tests.factories import MobileResourceFactory, UserFactory
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db
TOKEN = "metrics-token-0123456789"


def _scrape(client) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    response = client.get("/metrics", headers={"Authorization": f"Bearer {TOKEN}"})
    assert response.status_code == 200
    found = {}
    for family in text_string_to_metric_families(response.content.decode()):
        for sample in family.samples:
            found[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return found


def test_metrics_are_off_without_a_token_and_refused_with_a_wrong_one(client, settings):
    settings.METRICS_TOKEN = None
    assert client.get("/metrics").status_code == 404
    settings.METRICS_TOKEN = TOKEN
    assert client.get("/metrics").status_code == 401
    wrong = client.get("/metrics", headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 401
    assert wrong["WWW-Authenticate"].startswith("Bearer")


def test_runs_robots_and_requests_are_counted(client, settings):
    settings.METRICS_TOKEN = TOKEN
    robot = MobileResourceFactory()
    owner = UserFactory()
    done = completed_run(owner, robot, [(0.5, "cw", 10.0)])
    other = MobileResourceFactory(name="mobile-2", agent_token_name="mobile-2")
    running = completed_run(owner, other, [(0.5, "cw", 10.0)])
    Resource.objects.filter(pk=robot.pk).update(hold_reason="e-stop latched")
    Run.objects.filter(pk=running.pk).update(state=RunState.RUNNING)
    status = {"battery_v": 23.9, "estop": {"latched": True}, "link": {"state": "up"}}
    cache.set(
        _cache_key(robot.name),
        RobotHealth(name=robot.name, checked_at_s=time.time() - 3, reachable=True, status=status),
    )
    assert client.get("/accounts/login/").status_code == 200

    metrics = _scrape(client)
    assert metrics[("amazing_runs", (("state", "completed"),))] == 1
    assert metrics[("amazing_runs", (("state", "running"),))] == 1
    assert metrics[("amazing_runs", (("state", "failed"),))] == 0
    lag_key = (
        "amazing_run_collection_lag_seconds",
        (("resource", other.name), ("run", str(running.pk))),
    )
    assert lag_key in metrics
    assert not any(
        k[0] == "amazing_run_collection_lag_seconds" and ("run", str(done.pk)) in k[1]
        for k in metrics
    )
    named = (("resource", robot.name),)
    assert metrics[("amazing_resource_held", named)] == 1
    assert metrics[("amazing_robot_battery_volts", named)] == 23.9
    assert metrics[("amazing_robot_estop_latched", named)] == 1
    assert metrics[("amazing_robot_link_up", named)] == 1
    assert metrics[("amazing_robot_agent_reachable", named)] == 1
    assert 2.5 < metrics[("amazing_robot_health_age_seconds", named)] < 60
    logins = (
        "amazing_http_requests_total",
        (("method", "GET"), ("status", "2xx"), ("view", "account_login")),
    )
    assert metrics[logins] >= 1
