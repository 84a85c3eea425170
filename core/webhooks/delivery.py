"""Sending webhooks: what is due, one delivery at a time, retried and given up on.

A delivery is sent under its row's lock, in a transaction that records the try: a worker that
dies mid-try leaves it as it was, and it is sent again with the same ``webhook-id`` (at least
once). A webhook's deliveries go one at a time in the order of their events: a later one waits
while an earlier one is being retried. Retries back off from ``WEBHOOK_RETRY_FIRST_S``,
doubling, to at most ``WEBHOOK_RETRY_MAX_S`` apart, for ``WEBHOOK_RETRY_FOR_S`` after the
delivery was made; then it has failed, the webhook is paused and its owner told
(``webhook.paused``, an event of its own, whose e-mail is ``core.webhooks.handlers``'s).
"""

from __future__ import annotations

import json
import logging
from datetime import datetime, timedelta

from django.conf import settings
from django.db import transaction
from django.db.models import Exists, OuterRef, QuerySet
from django.utils import timezone

from core.crypto import decrypt
from core.events.models import Event
from core.events.services import event_record
from core.webhooks.guard import Refused, webhook_target
from core.webhooks.models import WebhookDelivery, WebhookSubscription
from core.webhooks.sender import Answer, signed_headers, webhook_post

logger = logging.getLogger(__name__)

SECRET_PURPOSE = b"webhook-secret"
PENDING = WebhookDelivery.State.PENDING
# Tries one pass makes at most (each up to the sender's timeouts); the rest, the next pass.
PASS_MAX = 20


def webhook_secret(subscription: WebhookSubscription) -> str:
    return decrypt(subscription.secret_encrypted, purpose=SECRET_PURPOSE)


def webhook_body(event: Event) -> str:
    """Standard Webhooks' envelope (``type``, ``timestamp``, ``data``) with the event's own
    fields, as ``GET /api/v1/events/`` shows them."""
    return json.dumps(
        {
            "type": event.type,
            "timestamp": event.occurred_at.isoformat(),
            "id": event.position,
            "subject": event.subject,
            "seq": event.seq,
            "version": event.version,
            "data": event.payload,
        },
        separators=(",", ":"),
        sort_keys=True,
    )


def webhook_message_id(event: Event) -> str:
    """The ``webhook-id``: one per event, the same on every try and for every webhook."""
    return f"evt_{event.position}"


def _retry_delay_s(attempts: int) -> float:
    first = settings.WEBHOOK_RETRY_FIRST_S
    return float(min(first * 2 ** max(attempts - 1, 0), settings.WEBHOOK_RETRY_MAX_S))


def _due(now: datetime) -> QuerySet[WebhookDelivery]:
    earlier = WebhookDelivery.objects.filter(
        subscription=OuterRef("subscription"),
        state=PENDING,
        event__position__lt=OuterRef("event__position"),
    )
    return (
        WebhookDelivery.objects.filter(
            state=PENDING,
            next_try_at__lte=now,
            subscription__paused_at__isnull=True,
            event__position__isnull=False,
        )
        .exclude(Exists(earlier))
        .order_by("next_try_at", "pk")
    )


def _record(delivery: WebhookDelivery, answer: Answer, now: datetime) -> float | None:
    """Write down one try; the seconds until the next, or None when there is none."""
    delivery.attempts += 1
    delivery.last_tried_at = now
    delivery.last_status = answer.status
    delivery.last_error = answer.error[:300]
    if answer.ok:
        delivery.state = WebhookDelivery.State.DELIVERED
        delivery.delivered_at = now
        delivery.next_try_at = None
        delivery.save()
        return None
    delay_s = _retry_delay_s(delivery.attempts)
    window_end = delivery.created_at + timedelta(seconds=settings.WEBHOOK_RETRY_FOR_S)
    if now + timedelta(seconds=delay_s) <= window_end:
        delivery.next_try_at = now + timedelta(seconds=delay_s)
        delivery.save()
        return delay_s
    delivery.state = WebhookDelivery.State.FAILED
    delivery.next_try_at = None
    delivery.save()
    _pause(delivery, now)
    return None


def _pause(delivery: WebhookDelivery, now: datetime) -> None:
    subscription = delivery.subscription
    hours = settings.WEBHOOK_RETRY_FOR_S / 3600
    reason = (
        f"event {delivery.event.position} ({delivery.event.type}) was not accepted in "
        f"{delivery.attempts} tries over {hours:g} h; last: {delivery.last_error}"
    )[:300]
    WebhookSubscription.objects.filter(pk=subscription.pk).update(
        paused_at=now, pause_reason=reason
    )
    event_record(
        subject=f"webhook:{subscription.pk}",
        type="webhook.paused",
        owner_id=subscription.owner_id,
        payload={"webhook": subscription.pk, "url": subscription.url, "reason": reason},
    )
    logger.warning("webhook %s paused: %s", subscription.pk, reason)


def webhook_delivery_try(delivery: WebhookDelivery, *, now: datetime) -> Answer:
    """One try, checked against the guard first (the name may resolve elsewhere now)."""
    subscription = delivery.subscription
    try:
        target = webhook_target(subscription.url)
    except Refused as exc:
        return Answer(None, f"refused: {exc}")
    body = webhook_body(delivery.event)
    headers = signed_headers(
        secret=webhook_secret(subscription),
        msg_id=webhook_message_id(delivery.event),
        sent_at=now,
        body=body,
    )
    return webhook_post(target, body=body, headers=headers)


def webhook_deliveries_send(*, limit: int = PASS_MAX) -> tuple[int, float | None]:
    """Send what is due, one delivery at a time, each under its row's lock: how many were
    tried, and in how many seconds the next pass is wanted (None: beat's, every minute)."""
    tried = 0
    soonest_s: float | None = None
    while tried < limit:
        with transaction.atomic():
            now = timezone.now()
            delivery = (
                _due(now)
                .select_related("subscription", "event")
                .select_for_update(skip_locked=True, of=("self",))
                .first()
            )
            if delivery is None:
                break
            answer = webhook_delivery_try(delivery, now=now)
            next_s = _record(delivery, answer, timezone.now())
        tried += 1
        if next_s is not None:
            soonest_s = next_s if soonest_s is None else min(soonest_s, next_s)
    if tried >= limit:
        return tried, 0.0  # more may be due now
    return tried, soonest_s
