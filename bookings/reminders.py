"""Reminders: a confirmed reservation about to start gets its ``reservation.starting_soon``
event once (its owner's e-mail is that event's reaction: ``bookings.handlers``)."""

from __future__ import annotations

from datetime import datetime, timedelta

from django.conf import settings
from django.db import transaction
from django.db.models import CharField, Exists, OuterRef, Value
from django.db.models.functions import Cast, Concat

from bookings.choices import ReservationState
from bookings.events import SUBJECT_PREFIX, reservation_event_record, subject_of
from bookings.models import Reservation
from core.events.models import Event
from core.events.selectors import events_of

STARTING_SOON = "reservation.starting_soon"


def reservations_due_for_reminder(*, now: datetime) -> list[int]:
    """Confirmed reservations starting within the lead that have not had their event."""
    lead = timedelta(seconds=settings.RESERVATION_REMINDER_LEAD_S)
    reminded = Event.objects.filter(
        type=STARTING_SOON,
        subject=Concat(Value(SUBJECT_PREFIX), Cast(OuterRef("pk"), CharField())),
    )
    return list(
        Reservation.objects.filter(
            state=ReservationState.CONFIRMED,
            start_at__gt=now,
            start_at__lte=now + lead,
        )
        .exclude(Exists(reminded))
        .values_list("pk", flat=True)
    )


def reservation_remind(*, reservation_id: int) -> bool:
    """Write the reservation's ``reservation.starting_soon`` if it is still confirmed and has
    none; True when this call wrote it. Under the reservation's row lock, with a unique index
    behind it (``event_once_per_subject``): two sweeps at once write one."""
    with transaction.atomic():
        reservation = (
            Reservation.objects.select_for_update()
            .filter(pk=reservation_id, state=ReservationState.CONFIRMED)
            .first()
        )
        if reservation is None:
            return False
        if events_of(subject=subject_of(reservation_id), type=STARTING_SOON).exists():
            return False
        reservation_event_record(STARTING_SOON, reservation, by=None, via="")
    return True
