from __future__ import annotations

from django.conf import settings
from django.db import models


class AuditEvent(models.Model):
    """Who did what, when, from where and why. Append-only.

    On PostgreSQL a trigger (migration 0002) refuses UPDATE and DELETE, so not even a
    careless admin script rewrites history.
    """

    at = models.DateTimeField(auto_now_add=True, db_index=True)
    # No database constraint and no cascade: deleting an account must not rewrite (or be
    # blocked by) the history; ``actor_name`` keeps who it was.
    actor = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        null=True,
        blank=True,
        on_delete=models.DO_NOTHING,
        db_constraint=False,
        related_name="+",
    )
    actor_name = models.CharField(max_length=150, blank=True)
    action = models.CharField(max_length=64, db_index=True)
    target_type = models.CharField(max_length=64, blank=True)
    target_id = models.CharField(max_length=64, blank=True)
    ip = models.GenericIPAddressField(null=True, blank=True)
    reason = models.TextField(blank=True)
    data = models.JSONField(default=dict, blank=True)

    class Meta:
        ordering = ["-at", "-pk"]
        indexes = [models.Index(fields=["target_type", "target_id"])]

    def __str__(self) -> str:
        target = f"{self.target_type}:{self.target_id}"
        return f"{self.at:%Y-%m-%d %H:%M:%S} {self.actor_name} {self.action} {target}"


class IdempotencyKey(models.Model):
    """The answer to a creating request sent with ``X-Idempotency-Key``, for replays.

    Written in the same transaction as the request's work (``core.audit.idempotency``).
    """

    user = models.ForeignKey(settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="+")
    key = models.CharField(max_length=128)
    method = models.CharField(max_length=8)
    path = models.CharField(max_length=255)
    request_hash = models.CharField(max_length=64)
    # Null only in rows of the previous release, which stored the key before the work.
    status = models.PositiveSmallIntegerField(null=True)
    response = models.JSONField(null=True)
    # Indexed for the expiry sweep, which deletes by age.
    created_at = models.DateTimeField(auto_now_add=True, db_index=True)

    class Meta:
        constraints = [
            models.UniqueConstraint(fields=["user", "key"], name="idempotency_key_unique"),
        ]

    def __str__(self) -> str:
        return f"{self.user_id}:{self.key}"


class EventCount(models.Model):
    """How often an event happened, by name and labels: Prometheus counters that every
    process of the portal adds to (workers, beat, collector, web) and ``/metrics`` reads.

    In the database because it is the one store every process shares in every deployment:
    the workers run in containers of their own (no shared folder for prometheus-client's
    multiprocess files, whose names are process ids that repeat across containers). The
    events counted are rare (failures, holds), so a row update each costs nothing.
    """

    name = models.CharField(max_length=100)
    # Canonical JSON of the labels ({"resource": "mobile-1"}), sorted keys.
    labels = models.CharField(max_length=300, default="{}")
    value = models.BigIntegerField(default=0)
    updated_at = models.DateTimeField(auto_now=True)

    class Meta:
        constraints = [
            models.UniqueConstraint(fields=["name", "labels"], name="event_count_unique"),
        ]

    def __str__(self) -> str:
        return f"{self.name}{self.labels} = {self.value}"
