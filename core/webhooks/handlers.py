"""The webhooks' reactions to events (``core.events.dispatch``): every event made into its
deliveries, and a paused webhook's owner e-mailed. Imported when the app is ready."""

from __future__ import annotations

from core.events.catalogue import EVENT_TYPES
from core.events.dispatch import handler
from core.events.models import Event
from core.webhooks import notifications, services
from core.webhooks.models import WebhookSubscription


def _any_webhook() -> bool:
    return WebhookSubscription.objects.exists()


# Without a webhook, events cost nothing more: no wake-up, no pass over them.
@handler("webhooks", types=sorted(EVENT_TYPES), active=_any_webhook)
def webhooks(event: Event) -> None:
    services.deliveries_for_event(event)


@handler("webhook-paused-mail", types=["webhook.paused"])
def webhook_paused_mail(event: Event) -> None:
    notifications.webhook_paused_notify(
        webhook_id=event.payload["webhook"], reason=event.payload["reason"]
    )
