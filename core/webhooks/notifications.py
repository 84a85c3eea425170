"""The e-mail a webhook's owner gets when it is paused."""

from __future__ import annotations

import logging

from django.conf import settings
from django.core.mail import send_mail

from core.webhooks.models import WebhookSubscription

logger = logging.getLogger(__name__)


def webhook_paused_notify(*, webhook_id: int, reason: str) -> int:
    """How many were sent: none when the webhook or its owner's address is gone, or when it
    was resumed since (the pause is over; nothing to do)."""
    subscription = (
        WebhookSubscription.objects.select_related("owner")
        .filter(pk=webhook_id, paused_at__isnull=False)
        .first()
    )
    if subscription is None or not subscription.owner.email:
        logger.info("webhook %s: no pause to tell of", webhook_id)
        return 0
    body = "\n".join(
        [
            f"Hello {subscription.owner.get_username()},",
            "",
            f"your webhook {subscription.url} is paused: {reason}",
            "",
            "Nothing is sent to it until you resume it "
            f"(POST /api/v1/webhooks/{subscription.pk}/resume/); the events meanwhile wait and "
            "go out in order then.",
            "",
            "— AMazING testbed",
        ]
    )
    return send_mail(
        f"Webhook paused: {subscription.url}",
        body,
        settings.DEFAULT_FROM_EMAIL,
        [subscription.owner.email],
    )
