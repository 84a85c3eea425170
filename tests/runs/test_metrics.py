"""``/metrics``: the system's state and the HTTP metrics for Prometheus, behind a token."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from datetime import timedelta

import pytest
from django.core.cache import cache
from django.utils import timezone
from prometheus_client.parser import text_string_to_metric_families

from basestation.client import AgentError
from bookings.leases import scheduler_sweep
from bookings.models import Resource
from bookings.scheduler import config as scheduler_config
from bookings.services import resource_hold
from core.audit.counters import event_count
from core.events.dispatch import events_dispatch
from portal.runs.models import Run
from portal.runs.services import staging
from portal.runs.services.health import RobotHealth, _cache_key
from portal.runs.services.reservations import reservation_create
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory
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


def _booked_run(owner, robot) -> Run:
    experiment = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 2.0}]
    )
    start = timezone.now() + timedelta(minutes=2)
    reservation = reservation_create(
        owner=owner,
        resource=robot,
        start_at=start,
        end_at=start + timedelta(seconds=10),
        experiment=experiment,
    )
    return Run.objects.get(reservation=reservation)


def test_staging_failures_scheduler_link_errors_and_holds_are_counted(
    client, settings, owner, mobile
):
    settings.METRICS_TOKEN = TOKEN
    assert _scrape(client)[("amazing_scheduler_link_errors_total", ())] == 0
    settings.AGENT_TOKENS = {"default": "x" * 32}
    mobile.agent_url = "http://127.0.0.1:9"  # discard port: nothing listens
    mobile.save()
    run = _booked_run(owner, mobile)
    for _ in range(2):
        with pytest.raises(AgentError):
            staging.run_stage(run_id=run.pk)
    settings.SCHEDULER = scheduler_config.from_env({"SCHEDULER_URL": "http://127.0.0.1:9"})
    assert scheduler_sweep() is None
    assert resource_hold(resource_id=mobile.pk, reason="e-stop latched")
    assert not resource_hold(resource_id=mobile.pk, reason="e-stop latched")  # held already
    # Counted by the hold's handler, once however often its pass runs.
    assert (
        _scrape(client)[("amazing_event_handler_backlog", (("handler", "robot-hold-count"),))] == 1
    )
    for _ in range(2):
        events_dispatch(name="robot-hold-count")

    metrics = _scrape(client)
    assert metrics[("amazing_event_handler_backlog", (("handler", "robot-hold-count"),))] == 0
    retrying = (("outcome", "retrying"), ("resource", mobile.name))
    assert metrics[("amazing_run_staging_failures_total", retrying)] == 2
    assert metrics[("amazing_scheduler_link_errors_total", ())] == 1
    assert metrics[("amazing_robot_holds_total", (("resource", mobile.name),))] == 1


@pytest.mark.django_db(transaction=True)
def test_counts_made_by_another_process_reach_the_scrape(client, settings):
    """The workers are processes (containers) of their own: what one counts is in the web's
    /metrics."""
    settings.METRICS_TOKEN = TOKEN
    db = settings.DATABASES["default"]
    env = dict(os.environ)
    env["DATABASE_URL"] = f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}"
    script = (
        "import django; django.setup()\n"
        "from core.audit.counters import event_count\n"
        "for _ in range(3):\n"
        "    event_count('run_staging_failures', resource='mobile-7', outcome='failed')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    failed = (("outcome", "failed"), ("resource", "mobile-7"))
    assert _scrape(client)[("amazing_run_staging_failures_total", failed)] == 3


def test_an_unknown_counter_is_refused():
    with pytest.raises(ValueError, match="unknown counter"):
        event_count("run_staging_failure", resource="mobile-1")
