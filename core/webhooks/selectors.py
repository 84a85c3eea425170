"""Reading webhooks: a user's own, and each one's deliveries, newest first."""

from __future__ import annotations

from django.db.models import QuerySet

from core.accounts.models import User
from core.webhooks.models import WebhookDelivery, WebhookSubscription


def webhooks_visible(*, user: User) -> QuerySet[WebhookSubscription]:
    return WebhookSubscription.objects.filter(owner=user).order_by("pk")


def webhook_deliveries(*, subscription: WebhookSubscription) -> QuerySet[WebhookDelivery]:
    return (
        WebhookDelivery.objects.filter(subscription=subscription)
        .select_related("event")
        .order_by("-event__position", "-pk")
    )
