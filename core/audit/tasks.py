"""Celery tasks of the audit app: thin wrappers around one service each."""

from __future__ import annotations

from celery import shared_task

from core.audit.idempotency import idempotency_keys_delete_expired as _delete_expired


@shared_task(time_limit=300, soft_time_limit=280)
def idempotency_keys_delete_expired() -> int:
    return _delete_expired()
