"""The Celery settings that make delivery at-least-once and keep mail from delaying runs."""

from __future__ import annotations

from pathlib import Path

import yaml
from django.conf import settings

from portal.celery import app as celery_app
from portal.processes import MAIL_QUEUE, RUNS_QUEUE, system_processes
from portal.runs.tasks import MAX_RETRIES

REPO = Path(__file__).resolve().parents[2]
MAIL_TASKS = {
    "core.events.tasks.events_dispatch_all",
    "core.webhooks.tasks.webhooks_send",
}


def _queue(name: str) -> str:
    return celery_app.amqp.router.route({}, name)["queue"].name


def _tasks() -> dict[str, object]:
    return {name: t for name, t in celery_app.tasks.items() if not name.startswith("celery.")}


def test_delivery_is_at_least_once_one_task_at_a_time():
    assert celery_app.conf.task_acks_late is True
    assert celery_app.conf.task_reject_on_worker_lost is True
    assert celery_app.conf.worker_prefetch_multiplier == 1
    assert celery_app.conf.broker_connection_max_retries is None


def test_mail_tasks_go_to_the_mail_queue_and_everything_else_to_the_runs_queue():
    assert set(_tasks()) >= MAIL_TASKS
    for name in _tasks():
        assert _queue(name) == (MAIL_QUEUE if name in MAIL_TASKS else RUNS_QUEUE), name


def test_each_queue_has_a_worker_of_its_own():
    specs = system_processes(
        python="py", portal_port=1, streams_port=3, agent_port=2, var_dir=settings.VAR_DIR
    )
    queues = {
        spec.name: spec.argv[spec.argv.index("--queues") + 1]
        for spec in specs
        if "--queues" in spec.argv
    }
    assert queues == {"worker": RUNS_QUEUE, "mail": MAIL_QUEUE}


def test_the_visibility_timeout_outlasts_every_task_and_every_retry_delay():
    """Redis hands an unacknowledged message to another worker after the visibility timeout:
    a task still running (or a retry still waiting) then would run twice at once."""
    timeout_s = celery_app.conf.broker_transport_options["visibility_timeout"]
    assert timeout_s == settings.CELERY_VISIBILITY_TIMEOUT_S
    for name, task in _tasks().items():
        limit_s = getattr(task, "time_limit", None) or celery_app.conf.task_time_limit
        assert limit_s, f"{name} has no time limit"
        retry_delay_s = 0.0
        if getattr(task, "autoretry_for", ()):
            # retry_backoff doubles up to retry_backoff_max (Celery's default 600 s).
            retry_delay_s = getattr(task, "retry_backoff_max", 600)
        if name in ("portal.runs.tasks.run_stage", "portal.runs.tasks.run_unstage"):
            retry_delay_s = min(30, 2**MAX_RETRIES)
        assert limit_s + retry_delay_s < timeout_s, name


def test_the_deployment_runs_a_worker_for_each_queue():
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    queues = {
        name: service["command"][service["command"].index("--queues") + 1]
        for name, service in compose["services"].items()
        if "worker" in service.get("command", []) and "celery" in service["command"]
    }
    assert sorted(queues.values()) == sorted([RUNS_QUEUE, MAIL_QUEUE]), queues
