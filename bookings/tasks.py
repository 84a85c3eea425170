"""Celery tasks for bookings: thin wrappers that take ids and call one service each."""

from __future__ import annotations

from celery import Task, shared_task
from django.utils import timezone

from bookings import leases, reminders

MAX_RETRIES = 5


@shared_task(time_limit=60, soft_time_limit=50)
def reservations_remind() -> None:
    """Each confirmed reservation about to start gets its ``reservation.starting_soon``, once
    (its owner is e-mailed by that event's handler)."""
    for reservation_id in reminders.reservations_due_for_reminder(now=timezone.now()):
        reminders.reservation_remind(reservation_id=reservation_id)


@shared_task(time_limit=120, soft_time_limit=110)
def scheduler_sweep() -> None:
    """Mirror the testbed scheduler's leases, cancel orphans, flag bookings (each flag an
    event, whose handler tells the owner and the admins)."""
    leases.scheduler_sweep()


@shared_task(
    bind=True,
    time_limit=60,
    soft_time_limit=50,
    autoretry_for=(OSError,),
    retry_backoff=True,
    max_retries=MAX_RETRIES,
)
def lease_cancel(self: Task, lease_uuid: str) -> None:
    # A failure is logged by the service and the next sweep cancels the lease as an orphan.
    leases.lease_release(lease_uuid=lease_uuid)
