"""Webhooks: made, changed, resumed and tried by their owners, and each event of theirs made
into one delivery per webhook that takes it (sending them: ``core.webhooks.delivery``)."""

from __future__ import annotations

import secrets
from collections.abc import Iterable

from django.conf import settings
from django.db import transaction
from django.db.models import Q
from django.utils import timezone

from core.accounts.models import User
from core.audit.services import audit_record
from core.crypto import encrypt
from core.errors import Conflict, InvalidInput, NotAllowed
from core.events.catalogue import EVENT_TYPES
from core.events.models import Event
from core.events.sequence import events_sequence
from core.events.services import event_record
from core.webhooks.delivery import PENDING, SECRET_PURPOSE
from core.webhooks.guard import Refused, webhook_target
from core.webhooks.models import WebhookDelivery, WebhookSubscription
from core.webhooks.tasks import webhooks_send

STAFF_ONLY_PREFIXES = ("robot.", "scheduler.")


# -- subscriptions ------------------------------------------------------------------------------


def _checked_url(url: str) -> str:
    try:
        webhook_target(url)
    except Refused as exc:
        raise InvalidInput.on_field("url", str(exc)) from None
    return url


def _checked_types(types: Iterable[str], *, staff_events: bool) -> list[str]:
    wanted = sorted(set(types))
    unknown = [t for t in wanted if t not in EVENT_TYPES]
    if unknown:
        raise InvalidInput.on_field("types", f"not event types: {', '.join(unknown)}")
    staff_only = [t for t in wanted if t.startswith(STAFF_ONLY_PREFIXES)]
    if staff_only and not staff_events:
        raise InvalidInput.on_field(
            "types", f"{', '.join(staff_only)}: staff's events, with staff_events only"
        )
    return wanted


def webhook_create(
    *,
    owner: User,
    url: str,
    description: str = "",
    types: Iterable[str] = (),
    staff_events: bool = False,
    ip: str | None = None,
) -> tuple[WebhookSubscription, str]:
    """A new webhook and its secret (``whsec_…``), which its owner sees this once."""
    if staff_events and not owner.is_testbed_admin:
        raise NotAllowed("Only staff, signed in with their second factor, take staff's events.")
    if WebhookSubscription.objects.filter(owner=owner).count() >= settings.WEBHOOKS_PER_USER_MAX:
        raise Conflict(
            f"You have {settings.WEBHOOKS_PER_USER_MAX} webhooks, the most one may have: "
            "delete one first."
        )
    secret = "whsec_" + secrets.token_urlsafe(32).replace("-", "+").replace("_", "/")
    with transaction.atomic():
        subscription = WebhookSubscription.objects.create(
            owner=owner,
            url=_checked_url(url),
            description=description,
            types=_checked_types(types, staff_events=staff_events),
            staff_events=staff_events,
            secret_encrypted=encrypt(secret, purpose=SECRET_PURPOSE),
        )
        audit_record(actor=owner, action="webhook.create", target=subscription, ip=ip, url=url)
    return subscription, secret


def webhook_update(
    *,
    subscription: WebhookSubscription,
    by: User,
    url: str | None = None,
    description: str | None = None,
    types: Iterable[str] | None = None,
    ip: str | None = None,
) -> WebhookSubscription:
    with transaction.atomic():
        locked = WebhookSubscription.objects.select_for_update().get(pk=subscription.pk)
        if url is not None:
            locked.url = _checked_url(url)
        if description is not None:
            locked.description = description
        if types is not None:
            locked.types = _checked_types(types, staff_events=locked.staff_events)
        locked.save()
        audit_record(actor=by, action="webhook.update", target=locked, ip=ip, url=locked.url)
    return locked


def webhook_delete(*, subscription: WebhookSubscription, by: User, ip: str | None = None) -> None:
    with transaction.atomic():
        audit_record(
            actor=by, action="webhook.delete", target=subscription, ip=ip, url=subscription.url
        )
        subscription.delete()


def webhook_resume(
    *, subscription: WebhookSubscription, by: User, ip: str | None = None
) -> WebhookSubscription:
    """Send again: what failed is tried once more from now, then what waited behind it."""
    now = timezone.now()
    with transaction.atomic():
        locked = WebhookSubscription.objects.select_for_update().get(pk=subscription.pk)
        locked.paused_at = None
        locked.pause_reason = ""
        locked.save(update_fields=["paused_at", "pause_reason"])
        # The failed delivery gets a new window, counted from now.
        locked.deliveries.filter(state=WebhookDelivery.State.FAILED).update(
            state=PENDING, next_try_at=now, created_at=now
        )
        locked.deliveries.filter(state=PENDING).update(next_try_at=now)
        audit_record(actor=by, action="webhook.resume", target=locked, ip=ip)
        transaction.on_commit(webhooks_send.delay)
    return locked


def webhook_test(*, subscription: WebhookSubscription, by: User, ip: str | None = None) -> Event:
    """A ``webhook.test`` event, for this webhook only; returns it, numbered."""
    with transaction.atomic():
        event = event_record(
            subject=f"webhook:{subscription.pk}",
            type="webhook.test",
            owner_id=subscription.owner_id,
            payload={"webhook": subscription.pk, "url": subscription.url, "reason": ""},
        )
        audit_record(actor=by, action="webhook.test", target=subscription, ip=ip)
    events_sequence()
    event.refresh_from_db()
    return event


# -- events into deliveries ---------------------------------------------------------------------


def _wanting(event: Event) -> list[int]:
    """The webhooks that take ``event``: a test only its own; the others, the webhooks of the
    event's owner (or, for the events of no one, staff's that take staff's events) that ask
    for its type or for every type. A pause is said to every webhook of its owner."""
    if event.type == "webhook.test":
        return list(
            WebhookSubscription.objects.filter(pk=event.payload["webhook"]).values_list(
                "pk", flat=True
            )
        )
    if event.owner_id is not None:
        mine = Q(owner_id=event.owner_id)
    else:
        mine = Q(staff_events=True, owner__is_staff=True, owner__is_active=True)
    return [
        pk
        for pk, types in WebhookSubscription.objects.filter(mine).values_list("pk", "types")
        if not types or event.type in types or event.type == "webhook.paused"
    ]


def deliveries_for_event(event: Event) -> int:
    """One delivery per webhook that takes ``event``, in the caller's transaction (the
    handler's: its cursor moves with them); made once however often it is asked."""
    now = timezone.now()
    made = WebhookDelivery.objects.bulk_create(
        [
            WebhookDelivery(subscription_id=pk, event=event, next_try_at=now)
            for pk in _wanting(event)
        ],
        ignore_conflicts=True,
    )
    if made:
        transaction.on_commit(webhooks_send.delay)
    return len(made)
