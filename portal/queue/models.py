"""Requests to run an experiment "as soon as possible": the queue books each in the first slot
that passes every booking rule, in fair-share order (``portal/queue/services.py``)."""

from __future__ import annotations

from django.conf import settings
from django.db import models

from bookings.models import Reservation, Resource
from portal.experiments.models import Experiment


class RequestState(models.TextChoices):
    WAITING = "waiting", "waiting"
    BOOKED = "booked", "booked"
    EXPIRED = "expired", "expired"
    CANCELLED = "cancelled", "cancelled"


class CampaignState(models.TextChoices):
    ACTIVE = "active", "active"
    PAUSED = "paused", "paused"
    CANCELLED = "cancelled", "cancelled"


class Campaign(models.Model):
    """A sweep of one-segment programs over parameter values, each run a queued request
    (``portal/queue/sweep.py``). ``spec`` is the campaign file as given."""

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="campaigns"
    )
    title = models.CharField(max_length=150)
    robot = models.ForeignKey(Resource, on_delete=models.PROTECT, related_name="+")
    spec = models.JSONField()
    state = models.CharField(
        max_length=16, choices=CampaignState.choices, default=CampaignState.ACTIVE
    )
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)
    # When its last run settled (completed, failed, expired or withdrawn): ``campaign.done``
    # was recorded then, once (``campaigns.campaign_done_check``).
    done_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["-created_at", "-pk"]

    def __str__(self) -> str:
        return self.title


class QueueRequest(models.Model):
    """Run ``experiment`` on ``robot`` (with ``nodes``, fixed nodes held with it) for
    ``duration_s``, starting no sooner than ``earliest_at`` and ending by ``latest_end_at``,
    inside the allowed hours of the testbed's day if given (``hours_from`` to ``hours_to``,
    local hours; a range past midnight, 22 to 6, is a night)."""

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="queue_requests"
    )
    experiment = models.ForeignKey(Experiment, on_delete=models.PROTECT, related_name="+")
    robot = models.ForeignKey(Resource, on_delete=models.PROTECT, related_name="+")
    nodes = models.ManyToManyField(Resource, blank=True, related_name="+")
    title = models.CharField(max_length=200, blank=True)
    duration_s = models.PositiveIntegerField()
    earliest_at = models.DateTimeField()
    latest_end_at = models.DateTimeField()
    hours_from = models.PositiveSmallIntegerField(null=True, blank=True)
    hours_to = models.PositiveSmallIntegerField(null=True, blank=True)
    state = models.CharField(
        max_length=16, choices=RequestState.choices, default=RequestState.WAITING
    )
    # Why it waits (the last pass's finding), why it expired, or why it was cancelled.
    reason = models.TextField(blank=True)
    # An admin's reordering (audited): a higher priority goes before the fair-share order.
    priority = models.IntegerField(default=0)
    reservation = models.OneToOneField(
        Reservation,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="queue_request",
    )
    # A campaign's run: its campaign and its parameters' values (``SweepRun.parameters``).
    campaign = models.ForeignKey(
        Campaign, null=True, blank=True, on_delete=models.CASCADE, related_name="requests"
    )
    parameters = models.JSONField(null=True, blank=True)
    submitted_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["submitted_at", "pk"]
        indexes = [models.Index(fields=["state", "submitted_at"])]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(latest_end_at__gt=models.F("earliest_at")),
                name="queue_request_latest_end_after_earliest",
            ),
            models.CheckConstraint(
                condition=models.Q(duration_s__gt=0), name="queue_request_duration_positive"
            ),
            models.CheckConstraint(
                condition=(
                    models.Q(hours_from__isnull=True, hours_to__isnull=True)
                    | models.Q(hours_from__lte=23, hours_to__gte=1, hours_to__lte=24)
                ),
                name="queue_request_hours_in_a_day",
            ),
        ]

    def __str__(self) -> str:
        return f"{self.title or self.experiment_id} ({self.state})"


class QueueControl(models.Model):
    """The queue's one switch: paused, by whom and why. One row (pk 1), made on first use."""

    paused = models.BooleanField(default=False)
    reason = models.TextField(blank=True)
    changed_by = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    changed_at = models.DateTimeField(null=True, blank=True)

    def __str__(self) -> str:
        return "paused" if self.paused else "running"
