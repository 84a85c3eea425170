"""A user's webhooks: a URL that is sent their events, signed, and the log of each delivery."""

from __future__ import annotations

from django.conf import settings
from django.db import models


class WebhookSubscription(models.Model):
    """A URL that is sent the owner's events (of ``types``; all when empty), signed with its
    own secret (Standard Webhooks). Staff subscriptions made with the second factor may also
    take the events of no one (``staff_events``: robots, the scheduler link)."""

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="webhooks"
    )
    url = models.URLField(max_length=500)
    description = models.CharField(max_length=200, blank=True)
    types = models.JSONField(default=list, blank=True)
    staff_events = models.BooleanField(default=False)
    # Encrypted at rest (core.crypto), shown to its owner once, at creation.
    secret_encrypted = models.TextField()
    created_at = models.DateTimeField(auto_now_add=True)
    # Set when a delivery failed for the whole retry window; nothing is sent until resumed.
    paused_at = models.DateTimeField(null=True, blank=True)
    pause_reason = models.CharField(max_length=300, blank=True)

    class Meta:
        ordering = ["pk"]

    def __str__(self) -> str:
        return f"{self.owner_id}: {self.url}"


class WebhookDelivery(models.Model):
    """One event for one subscription, tried until its URL answers 2xx or the retry window
    ends; the same ``webhook-id`` on every try."""

    class State(models.TextChoices):
        PENDING = "pending"
        DELIVERED = "delivered"
        FAILED = "failed"

    subscription = models.ForeignKey(
        WebhookSubscription, on_delete=models.CASCADE, related_name="deliveries"
    )
    event = models.ForeignKey("events.Event", on_delete=models.CASCADE, related_name="+")
    state = models.CharField(max_length=12, choices=State.choices, default=State.PENDING)
    attempts = models.PositiveIntegerField(default=0)
    created_at = models.DateTimeField(auto_now_add=True)
    next_try_at = models.DateTimeField(null=True, blank=True)
    last_tried_at = models.DateTimeField(null=True, blank=True)
    # The last answer's HTTP status (none when there was no answer), or why there was none.
    last_status = models.PositiveSmallIntegerField(null=True, blank=True)
    last_error = models.CharField(max_length=300, blank=True)
    delivered_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["pk"]
        constraints = [
            models.UniqueConstraint(
                fields=["subscription", "event"], name="webhook_delivery_once_per_event"
            ),
        ]
        indexes = [
            # The sender's question: what is due, oldest first.
            models.Index(
                fields=["next_try_at"],
                condition=models.Q(state="pending"),
                name="webhook_delivery_due",
            ),
        ]

    def __str__(self) -> str:
        return f"{self.subscription_id}/{self.event_id} {self.state}"
