"""Celery tasks for runs and robots: thin wrappers that take ids and call one service each.

Every task is safe to run twice (a message is delivered again when its worker dies before
acknowledging it): each service re-reads the database and does only what is still due. The
sweeps re-queue whatever is still due, so a task lost with a broker or worker is redone.
Mail goes to its own queue (settings ``CELERY_TASK_ROUTES``).
"""

from __future__ import annotations

import logging

from celery import Task, shared_task
from django.utils import timezone

from basestation.client import AgentError
from core.health import SWEEP, heartbeat_record
from core.pending import pending_taken, queue_once
from portal.runs.services import collection, dry_run, health, self_check, staging

logger = logging.getLogger(__name__)

MAX_RETRIES = 5


@shared_task(time_limit=30, soft_time_limit=25)
def runs_sweep() -> None:
    """Find runs due for staging, withdrawal or collection, runs due whose booking does not
    hold them (held: ``run_hold``), and queue one task each, unless one for that run is still
    waiting (``core.pending``): a worker behind never piles up copies, and what it has not
    reached yet is still there when it does.
    """
    now = timezone.now()
    for run_id in staging.runs_due_for_staging(now=now).values_list("pk", flat=True):
        _queue(run_stage, run_id)
    for run_id in staging.runs_held_from_staging(now=now).values_list("pk", flat=True):
        _queue(run_hold, run_id)
    for run_id in staging.runs_due_for_withdrawal().values_list("pk", flat=True):
        _queue(run_unstage, run_id)
    for run_id in collection.runs_due_for_collection(now=now).values_list("pk", flat=True):
        _queue(run_collect, run_id)
    for dry_run_id in dry_run.dry_runs_next():
        _queue(dry_run_execute, dry_run_id)
    heartbeat_record(SWEEP)


def _queue(task: Task, subject_id: int) -> None:
    queue_once(task, f"{task.name}:{subject_id}", args=(subject_id,))


def _started(task: Task, subject_id: int) -> None:
    pending_taken(f"{task.name}:{subject_id}")


def _retry_if_transient(task: Task, exc: AgentError) -> None:
    if not exc.retryable:
        raise exc
    countdown_s = min(30, 2**task.request.retries)
    logger.warning("%s: %s; retry in %ss", task.name, exc, countdown_s)
    raise task.retry(exc=exc, countdown=countdown_s, max_retries=MAX_RETRIES)


@shared_task(time_limit=180, soft_time_limit=170)
def dry_run_execute(dry_run_id: int) -> None:
    """Run a dry run if a simulator place is free (the sweep asks again while it waits), then
    start the next in line at once."""
    _started(dry_run_execute, dry_run_id)
    if dry_run.dry_run_execute(dry_run_id):
        for next_id in dry_run.dry_runs_next():
            dry_run_execute.delay(next_id)


@shared_task(bind=True, time_limit=60, soft_time_limit=50)
def run_stage(self: Task, run_id: int) -> None:
    _started(run_stage, run_id)
    try:
        staging.run_stage(run_id=run_id)
    except AgentError as exc:
        _retry_if_transient(self, exc)


@shared_task(time_limit=30, soft_time_limit=25)
def run_hold(run_id: int) -> None:
    """Keep a run its booking does not hold off its agent (cancelled or failed, with why)."""
    _started(run_hold, run_id)
    staging.run_hold(run_id=run_id)


@shared_task(bind=True, time_limit=60, soft_time_limit=50)
def run_unstage(self: Task, run_id: int) -> None:
    _started(run_unstage, run_id)
    try:
        staging.run_unstage(run_id=run_id)
    except AgentError as exc:
        _retry_if_transient(self, exc)


@shared_task(time_limit=120, soft_time_limit=110)
def run_collect(run_id: int) -> None:
    # No retry here: the next sweep collects again, resuming after the last stored sample.
    _started(run_collect, run_id)
    try:
        collection.run_collect(run_id=run_id)
    except AgentError as exc:
        logger.warning("run %s: collection deferred: %s", run_id, exc)


@shared_task(time_limit=30, soft_time_limit=25)
def robots_health_sweep() -> None:
    """Queue a health check of every robot."""
    for resource_id in health.robots_to_check().values_list("pk", flat=True):
        _queue(robot_health_check, resource_id)


@shared_task(time_limit=300, soft_time_limit=280)
def dry_runs_delete_expired() -> int:
    """Hourly: dry runs and their samples past ``DRY_RUN_KEEP_S`` are deleted."""
    return dry_run.dry_runs_delete_expired()


@shared_task(time_limit=120, soft_time_limit=100)
def self_checks_book_scheduled() -> int:
    """Every few minutes: each robot's daily self-check booked half a day ahead."""
    return len(self_check.self_checks_book_scheduled())


@shared_task(time_limit=30, soft_time_limit=25)
def robot_health_check(resource_id: int) -> None:
    _started(robot_health_check, resource_id)
    health.robot_health_check(resource_id=resource_id)
