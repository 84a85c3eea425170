from __future__ import annotations

from django.conf import settings
from django.db import models

from core.events.catalogue import ONCE_PER_SUBJECT


class Event(models.Model):
    """Something that happened, written in the transaction that made it happen. Append-only.

    ``position`` and ``seq`` are empty until the sequencer numbers the row after its commit
    (``core.events.services.events_sequence``); readers see only numbered rows.
    """

    # What it is about: "reservation:42", "run:17".
    subject = models.CharField(max_length=80)
    type = models.CharField(max_length=48)
    version = models.PositiveSmallIntegerField(default=1)
    payload = models.JSONField(default=dict)
    # Whose it is: they (and only they, besides staff) read it. None: staff only.
    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL,
        null=True,
        blank=True,
        on_delete=models.CASCADE,
        related_name="+",
    )
    occurred_at = models.DateTimeField()
    # One order for every event, the order their transactions committed in.
    position = models.BigIntegerField(null=True, blank=True, unique=True)
    # The subject's own count: 1 for its first event.
    seq = models.PositiveIntegerField(null=True, blank=True)

    class Meta:
        ordering = ["position"]
        constraints = [
            models.UniqueConstraint(fields=["subject", "seq"], name="event_subject_seq_unique"),
            # The types that happen once to a subject (catalogue.ONCE_PER_SUBJECT).
            models.UniqueConstraint(
                fields=["subject", "type"],
                condition=models.Q(type__in=ONCE_PER_SUBJECT),
                name="event_once_per_subject",
            ),
        ]
        indexes = [
            models.Index(fields=["owner", "position"], name="event_owner_position"),
            # The sequencer's work: the few rows not numbered yet.
            models.Index(
                fields=["id"],
                condition=models.Q(position__isnull=True),
                name="event_unsequenced",
            ),
        ]

    def __str__(self) -> str:
        return f"{self.position or '-'} {self.type} {self.subject}"


class EventCursor(models.Model):
    """How far one handler has read the events (``core.events.dispatch``): the position of
    the last event it has handled. A handler new to a database starts at the first event."""

    handler = models.CharField(max_length=64, primary_key=True)
    position = models.BigIntegerField(default=0)
    updated_at = models.DateTimeField(auto_now=True)

    def __str__(self) -> str:
        return f"{self.handler} @ {self.position}"
