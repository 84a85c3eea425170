"""Celery tasks for bookings: thin wrappers that take ids and call one service each."""

from __future__ import annotations

from celery import Task, shared_task
from django.db import transaction
from django.utils import timezone

from bookings import leases, notifications, reminders
from core.audit.once import claim_once, task_once_key

MAX_RETRIES = 5


@shared_task(
    bind=True,
    time_limit=60,
    soft_time_limit=50,
    autoretry_for=(OSError,),
    retry_backoff=True,
    max_retries=MAX_RETRIES,
)
def reservation_notify(
    self: Task,
    kind: str,
    reservation_id: int,
    *,
    blackout_id: int | None = None,
    via: str = "",
) -> None:
    # Mail servers fail transiently (OSError covers SMTP connection errors); retry those only.
    # A message delivered again (its worker died) finds its claim and sends nothing twice.
    with transaction.atomic():
        if claim_once(task_once_key(self.name, self.request.id)):
            notifications.reservation_notify(kind, reservation_id, blackout_id=blackout_id, via=via)


@shared_task(time_limit=60, soft_time_limit=50)
def reservations_remind() -> None:
    """E-mail owners whose confirmed reservations start within the reminder lead, once."""
    for reservation_id in reminders.reservations_due_for_reminder(now=timezone.now()):
        if reminders.reminder_claim(reservation_id=reservation_id):
            reservation_notify.delay("reminder", reservation_id)


@shared_task(time_limit=120, soft_time_limit=110)
def scheduler_sweep() -> None:
    """Mirror the testbed scheduler's leases, cancel orphans, flag bookings; tell owners."""
    result = leases.scheduler_sweep()
    if result is None:
        return
    for kind, reservation_id in result.notices:
        reservation_notify.delay(kind, reservation_id)


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
