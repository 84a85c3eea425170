"""The webhooks' Celery task: a pass over the deliveries that are due
(``core.webhooks.delivery``)."""

from __future__ import annotations

from celery import shared_task

from core.webhooks import delivery


@shared_task(time_limit=300, soft_time_limit=280)
def webhooks_send() -> int:
    tried, next_pass_s = delivery.webhook_deliveries_send()
    if next_pass_s is not None:
        webhooks_send.apply_async(countdown=next_pass_s)
    return tried
