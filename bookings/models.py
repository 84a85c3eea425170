from __future__ import annotations

from django.conf import settings
from django.db import models

from bookings.choices import ReservationState, ResourceKind


class Resource(models.Model):
    """A bookable thing on the rooftop: the mobile node or one of the fixed nodes."""

    name = models.SlugField(max_length=64, unique=True)
    kind = models.CharField(max_length=8, choices=ResourceKind.choices)
    description = models.CharField(max_length=200, blank=True)
    # Mobile nodes only: where their base-station agent listens, and which configured
    # token (a name in settings.AGENT_TOKENS, never the secret itself) authenticates to it.
    agent_url = models.URLField(blank=True)
    agent_token_name = models.CharField(max_length=64, default="default", blank=True)
    max_velocity_mps = models.FloatField(null=True, blank=True)
    max_accel_mps2 = models.FloatField(null=True, blank=True)
    enabled = models.BooleanField(default=True)

    class Meta:
        ordering = ["kind", "name"]
        constraints = [
            models.CheckConstraint(
                condition=~models.Q(kind=ResourceKind.MOBILE)
                | (models.Q(max_velocity_mps__gt=0) & models.Q(max_accel_mps2__gt=0)),
                name="resource_mobile_has_limits",
            ),
        ]

    def __str__(self) -> str:
        return self.name

    @property
    def is_mobile(self) -> bool:
        return self.kind == ResourceKind.MOBILE


class Reservation(models.Model):
    """A resource held by a user for ``[start_at, end_at)``."""

    resource = models.ForeignKey(Resource, on_delete=models.PROTECT, related_name="reservations")
    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="reservations"
    )
    start_at = models.DateTimeField()
    end_at = models.DateTimeField()
    state = models.CharField(
        max_length=16, choices=ReservationState.choices, default=ReservationState.CONFIRMED
    )
    created_at = models.DateTimeField(auto_now_add=True)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        ordering = ["start_at"]
        indexes = [models.Index(fields=["resource", "start_at", "end_at"])]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(end_at__gt=models.F("start_at")),
                name="reservation_end_after_start",
            ),
        ]

    def __str__(self) -> str:
        return f"{self.resource} {self.start_at:%Y-%m-%d %H:%M}-{self.end_at:%H:%M}"
