"""Side effects of at-least-once tasks that must happen once: claimed by the message's key.

Celery delivers a task again when its worker died before acknowledging it, with the same
task id. A task whose effect is not idempotent by itself (an e-mail) claims the key
``<task name>:<task id>`` in the same transaction as the work: a redelivery finds the key
and does nothing; a failure rolls the claim back with the work, so a retry does it again.
The one window left — the worker dies after the mail left and before the commit — sends it
twice, never zero times.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from django.conf import settings
from django.db import IntegrityError, transaction
from django.utils import timezone

from core.audit.models import TaskOnce


def claim_once(key: str) -> bool:
    """Claim ``key`` inside the caller's transaction; False if it was claimed before.

    A concurrent claim of the same key waits on the unique index until the first commits
    (then False) or rolls back (then True).
    """
    if not transaction.get_connection().in_atomic_block:
        raise RuntimeError("claim_once belongs inside the transaction that does the work")
    try:
        with transaction.atomic():
            TaskOnce.objects.create(key=key)
    except IntegrityError:
        return False
    return True


def task_once_key(name: str, task_id: str | None) -> str:
    if not task_id:
        raise ValueError(f"{name}: a task message without an id cannot be claimed once")
    return f"{name}:{task_id}"


def task_once_delete_expired(*, now: datetime | None = None) -> int:
    """Forget claims older than a redelivery could come (the broker's visibility timeout),
    with a margin: the same lifetime as idempotency keys, at least."""
    now = now or timezone.now()
    keep_s = max(settings.IDEMPOTENCY_KEY_TTL_S, 2 * settings.CELERY_VISIBILITY_TIMEOUT_S)
    deleted, _ = TaskOnce.objects.filter(created_at__lte=now - timedelta(seconds=keep_s)).delete()
    return deleted
